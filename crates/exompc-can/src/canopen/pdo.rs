//! PDOs (process data objects, CiA 301 §7.2.2): the mapping of object-dictionary entries into
//! the 8 bytes of a frame, configured by SDO through the communication parameters
//! (0x1400+n RPDO, 0x1800+n TPDO: COB-ID, transmission type) and the mapping parameters
//! (0x1600+n, 0x1A00+n: `index << 16 | sub << 8 | bits`).

use super::od::{DataType, ObjectDictionary};
use super::{frame, std_id};
use crate::CanFrame;

/// Bit 31 of a PDO COB-ID entry: the PDO is not valid (disabled).
pub const COB_ID_INVALID: u32 = 0x8000_0000;
/// Transmission type: acyclic synchronous (on the next SYNC after a change).
pub const TT_SYNC_ACYCLIC: u8 = 0;
/// Transmission type: event-driven, manufacturer-specific (sent when the value changes).
pub const TT_EVENT: u8 = 0xFE;
/// Transmission type: event-driven, device profile (sent when the value changes).
pub const TT_EVENT_PROFILE: u8 = 0xFF;

/// Which side of the node a PDO is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Received by the node (RPDO: 0x1400/0x1600).
    Rx,
    /// Transmitted by the node (TPDO: 0x1800/0x1A00).
    Tx,
}

impl Direction {
    /// The communication parameter index of PDO `num` (0-based).
    pub fn comm_index(self, num: u8) -> u16 {
        match self {
            Direction::Rx => 0x1400 + u16::from(num),
            Direction::Tx => 0x1800 + u16::from(num),
        }
    }

    /// The mapping parameter index of PDO `num` (0-based).
    pub fn map_index(self, num: u8) -> u16 {
        self.comm_index(num) + 0x200
    }
}

/// One mapped object.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mapped {
    /// The object's index.
    pub index: u16,
    /// Its sub-index.
    pub sub: u8,
    /// Its length in bits (8, 16 or 32 here).
    pub bits: u8,
}

impl Mapped {
    /// A mapped object.
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        Self { index, sub, bits }
    }

    /// The mapping entry value.
    pub fn encode(self) -> u32 {
        u32::from(self.index) << 16 | u32::from(self.sub) << 8 | u32::from(self.bits)
    }

    /// The object of a mapping entry value.
    pub fn decode(v: u32) -> Self {
        Self {
            index: (v >> 16) as u16,
            sub: (v >> 8) as u8,
            bits: v as u8,
        }
    }
}

/// The configuration of one PDO.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PdoConfig {
    /// The COB-ID (11 bit).
    pub cob_id: u16,
    /// The transmission type (1..=240: every n-th SYNC; 0xFE/0xFF: on change).
    pub transmission_type: u8,
    /// The mapped objects, in frame order (at most 64 bits together).
    pub mapping: Vec<Mapped>,
}

impl PdoConfig {
    /// The SDO writes (index, sub, little-endian value) that configure PDO `num` of `dir` on a
    /// node, in the order CiA 301 requires: disable, transmission type, clear the mapping,
    /// write the entries, set their number, enable.
    pub fn sdo_writes(&self, dir: Direction, num: u8) -> Vec<(u16, u8, Vec<u8>)> {
        let comm = dir.comm_index(num);
        let map = dir.map_index(num);
        let cob = u32::from(self.cob_id);
        let mut w = vec![
            (comm, 1, (cob | COB_ID_INVALID).to_le_bytes().to_vec()),
            (comm, 2, vec![self.transmission_type]),
            (map, 0, vec![0]),
        ];
        for (i, m) in self.mapping.iter().enumerate() {
            w.push((map, i as u8 + 1, m.encode().to_le_bytes().to_vec()));
        }
        w.push((map, 0, vec![self.mapping.len() as u8]));
        w.push((comm, 1, cob.to_le_bytes().to_vec()));
        w
    }

    /// The byte layout of the mapping (`None` when an entry is not a whole number of bytes or
    /// the total passes 8 bytes).
    pub fn layout(&self) -> Option<Layout> {
        Layout::new(&self.mapping)
    }
}

/// Where each mapped object lies in the frame: no allocation when packing or unpacking.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    fields: [(u16, u8, u8, u8); 8],
    n: usize,
    len: usize,
}

impl Layout {
    /// The layout of a mapping.
    pub fn new(mapping: &[Mapped]) -> Option<Self> {
        let mut fields = [(0, 0, 0, 0); 8];
        let mut off = 0usize;
        if mapping.len() > 8 {
            return None;
        }
        for (i, m) in mapping.iter().enumerate() {
            if m.bits == 0 || m.bits % 8 != 0 || m.bits > 32 {
                return None;
            }
            let size = usize::from(m.bits / 8);
            if off + size > 8 {
                return None;
            }
            fields[i] = (m.index, m.sub, off as u8, size as u8);
            off += size;
        }
        Some(Self {
            fields,
            n: mapping.len(),
            len: off,
        })
    }

    /// The frame length in bytes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// `true` when nothing is mapped.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    fn find(&self, index: u16, sub: u8) -> Option<(usize, usize)> {
        self.fields[..self.n]
            .iter()
            .find(|f| f.0 == index && f.1 == sub)
            .map(|f| (usize::from(f.2), usize::from(f.3)))
    }

    /// `true` when (index, sub) is mapped.
    pub fn contains(&self, index: u16, sub: u8) -> bool {
        self.find(index, sub).is_some()
    }

    /// The raw little-endian value of (index, sub) in `data`, zero-extended (`None` when it is
    /// not mapped or `data` is too short).
    pub fn get(&self, data: &[u8], index: u16, sub: u8) -> Option<u32> {
        let (off, size) = self.find(index, sub)?;
        let bytes = data.get(off..off + size)?;
        let mut b = [0u8; 4];
        b[..size].copy_from_slice(bytes);
        Some(u32::from_le_bytes(b))
    }

    /// Write the low bytes of `value` as (index, sub) into `buf`; `false` when not mapped.
    pub fn put(&self, buf: &mut [u8; 8], index: u16, sub: u8, value: u32) -> bool {
        match self.find(index, sub) {
            Some((off, size)) => {
                buf[off..off + size].copy_from_slice(&value.to_le_bytes()[..size]);
                true
            }
            None => false,
        }
    }

    /// The mapped objects with their byte offsets and sizes.
    pub fn fields(&self) -> impl Iterator<Item = (u16, u8, usize, usize)> + '_ {
        self.fields[..self.n]
            .iter()
            .map(|f| (f.0, f.1, usize::from(f.2), usize::from(f.3)))
    }
}

/// A PDO as a node runs it, read from its object dictionary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ActivePdo {
    /// Rx or Tx.
    pub dir: Direction,
    /// 0-based PDO number.
    pub num: u8,
    /// The COB-ID.
    pub cob_id: u16,
    /// The transmission type.
    pub transmission_type: u8,
    /// The layout.
    pub layout: Layout,
}

/// The valid PDOs of `dir` configured in `od` (PDOs 1..=4; a disabled, empty or unreadable
/// one is skipped).
pub fn active(od: &ObjectDictionary, dir: Direction) -> Vec<ActivePdo> {
    let mut out = Vec::new();
    for num in 0..4u8 {
        let comm = dir.comm_index(num);
        let map = dir.map_index(num);
        let Some(cob) = od.get(comm, 1).map(|v| v as u32) else {
            continue;
        };
        if cob & COB_ID_INVALID != 0 {
            continue;
        }
        let tt = od.get(comm, 2).unwrap_or(i64::from(TT_EVENT_PROFILE)) as u8;
        let n = od.get(map, 0).unwrap_or(0) as u8;
        let mapping: Vec<Mapped> = (1..=n)
            .filter_map(|s| od.get(map, s).map(|v| Mapped::decode(v as u32)))
            .collect();
        if mapping.is_empty() {
            continue;
        }
        if let Some(layout) = Layout::new(&mapping) {
            out.push(ActivePdo {
                dir,
                num,
                cob_id: (cob & 0x7FF) as u16,
                transmission_type: tt,
                layout,
            });
        }
    }
    out
}

impl ActivePdo {
    /// The TPDO frame with the current values of the mapped objects.
    pub fn pack(&self, od: &ObjectDictionary) -> CanFrame {
        let mut buf = [0u8; 8];
        for (index, sub, off, size) in self.layout.fields() {
            if let Some(e) = od.entry(index, sub) {
                let b = e.bytes();
                let n = size.min(b.len());
                buf[off..off + n].copy_from_slice(&b[..n]);
            }
        }
        frame(self.cob_id, &buf[..self.layout.len()])
    }

    /// Apply a received RPDO to `od`; the objects written, or `None` when the frame is not
    /// this PDO or too short (CiA 301: a too-short PDO is not processed).
    pub fn apply(&self, f: &CanFrame, od: &mut ObjectDictionary) -> Option<Vec<(u16, u8)>> {
        if std_id(f) != Some(self.cob_id) || f.is_remote() || f.len() < self.layout.len() {
            return None;
        }
        let mut written = Vec::with_capacity(self.layout.n);
        for (index, sub, off, size) in self.layout.fields() {
            od.set_bytes(index, sub, &f.data()[off..off + size]);
            written.push((index, sub));
        }
        Some(written)
    }
}

/// Add the communication and mapping parameter entries of PDOs 1..=4 of `dir` to `od`, all
/// disabled, for a node whose PDOs the master configures.
pub fn add_parameters(od: &mut ObjectDictionary, dir: Direction, node: super::NodeId) {
    use super::od::Access;
    let base = match dir {
        Direction::Rx => super::cob::RPDO,
        Direction::Tx => super::cob::TPDO,
    };
    for num in 0..4u8 {
        let comm = dir.comm_index(num);
        let map = dir.map_index(num);
        let cob = u32::from(node.cob(base[usize::from(num)])) | COB_ID_INVALID;
        od.add(comm, 0, DataType::U8, Access::Const, false, 2)
            .add(comm, 1, DataType::U32, Access::Rw, false, i64::from(cob))
            .add(comm, 2, DataType::U8, Access::Rw, false, 1)
            .add(map, 0, DataType::U8, Access::Rw, false, 0);
        for s in 1..=8 {
            od.add(map, s, DataType::U32, Access::Rw, false, 0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::od::Access;
    use super::super::NodeId;
    use super::*;

    #[test]
    fn configuration_by_sdo_then_packing() {
        let node = NodeId::new(2).unwrap();
        let mut od = ObjectDictionary::new();
        add_parameters(&mut od, Direction::Tx, node);
        add_parameters(&mut od, Direction::Rx, node);
        od.add(0x6041, 0, DataType::U16, Access::Ro, true, 0x0237)
            .add(0x6064, 0, DataType::I32, Access::Ro, true, -123_456)
            .add(0x6071, 0, DataType::I16, Access::Rw, true, 0)
            .add(0x6040, 0, DataType::U16, Access::Rw, true, 0);
        let tx = PdoConfig {
            cob_id: 0x182,
            transmission_type: 1,
            mapping: vec![Mapped::new(0x6041, 0, 16), Mapped::new(0x6064, 0, 32)],
        };
        let rx = PdoConfig {
            cob_id: 0x202,
            transmission_type: 1,
            mapping: vec![Mapped::new(0x6040, 0, 16), Mapped::new(0x6071, 0, 16)],
        };
        let w = tx.sdo_writes(Direction::Tx, 0);
        assert_eq!(w[0], (0x1800, 1, vec![0x82, 0x01, 0x00, 0x80]));
        assert_eq!(w[3], (0x1A00, 1, vec![0x10, 0x00, 0x41, 0x60]));
        assert_eq!(w.last().unwrap(), &(0x1800, 1, vec![0x82, 0x01, 0, 0]));
        assert!(
            active(&od, Direction::Tx).is_empty(),
            "all disabled at first"
        );
        for (i, s, v) in w.iter().chain(rx.sdo_writes(Direction::Rx, 0).iter()) {
            od.write(*i, *s, v).unwrap();
        }
        let t = active(&od, Direction::Tx);
        assert_eq!(t.len(), 1);
        let f = t[0].pack(&od);
        assert_eq!(std_id(&f), Some(0x182));
        let mut expect = vec![0x37, 0x02];
        expect.extend_from_slice(&(-123_456i32).to_le_bytes());
        assert_eq!(f.data(), &expect[..]);
        let lay = tx.layout().unwrap();
        assert_eq!(
            lay.get(f.data(), 0x6064, 0).map(|v| v as i32),
            Some(-123_456)
        );
        assert_eq!(lay.get(f.data(), 0x6041, 0), Some(0x0237));
        assert_eq!(lay.get(f.data(), 0x6077, 0), None);
        let r = active(&od, Direction::Rx);
        let mut buf = [0u8; 8];
        let rl = rx.layout().unwrap();
        assert!(rl.put(&mut buf, 0x6040, 0, 0x0F));
        assert!(rl.put(&mut buf, 0x6071, 0, (-250i16) as u16 as u32));
        let rf = frame(0x202, &buf[..rl.len()]);
        assert_eq!(
            r[0].apply(&rf, &mut od),
            Some(vec![(0x6040, 0), (0x6071, 0)])
        );
        assert_eq!(od.get(0x6071, 0), Some(-250));
        assert_eq!(od.get(0x6040, 0), Some(0x0F));
        assert_eq!(
            r[0].apply(&frame(0x202, &[1, 2, 3]), &mut od),
            None,
            "too short"
        );
        // Layouts refuse what does not fit.
        assert!(Layout::new(&[
            Mapped::new(1, 0, 32),
            Mapped::new(2, 0, 32),
            Mapped::new(3, 0, 8)
        ])
        .is_none());
        assert!(Layout::new(&[Mapped::new(1, 0, 12)]).is_none());
    }
}
