//! An object dictionary for emulated nodes: entries addressed by (index, sub-index), each
//! with a data type, an access right and whether it may be mapped into a PDO. Values are stored
//! little-endian as on the bus. Writes through [`ObjectDictionary::write`] are checked the way
//! an SDO server checks them (access, length, allowed values, PDO mapping rules) and fail with
//! the CiA 301 abort code.

use super::sdo::AbortCode;
use std::collections::BTreeMap;

/// CiA 301 basic data types used here.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataType {
    /// UNSIGNED8.
    U8,
    /// UNSIGNED16.
    U16,
    /// UNSIGNED32.
    U32,
    /// INTEGER8.
    I8,
    /// INTEGER16.
    I16,
    /// INTEGER32.
    I32,
    /// VISIBLE_STRING (any length).
    VisibleString,
    /// DOMAIN (any length).
    Domain,
}

impl DataType {
    /// The size in bytes, `None` for the variable-length types.
    pub fn size(self) -> Option<usize> {
        match self {
            DataType::U8 | DataType::I8 => Some(1),
            DataType::U16 | DataType::I16 => Some(2),
            DataType::U32 | DataType::I32 => Some(4),
            DataType::VisibleString | DataType::Domain => None,
        }
    }

    fn signed(self) -> bool {
        matches!(self, DataType::I8 | DataType::I16 | DataType::I32)
    }
}

/// Access rights of an entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read only (the node may change it, the bus may not).
    Ro,
    /// Write only.
    Wo,
    /// Read and write.
    Rw,
    /// Constant.
    Const,
}

/// Which values a write may store.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Allowed {
    /// Any value of the type.
    Any,
    /// An inclusive range.
    Range(i64, i64),
    /// One of a list.
    OneOf(Vec<i64>),
}

/// One entry of the dictionary.
#[derive(Clone, Debug)]
pub struct Entry {
    /// The data type.
    pub dtype: DataType,
    /// The access right.
    pub access: Access,
    /// May be mapped into a PDO.
    pub pdo_mappable: bool,
    /// Allowed values for writes from the bus.
    pub allowed: Allowed,
    value: Vec<u8>,
}

impl Entry {
    /// The stored bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.value
    }
}

/// The value of a little-endian integer of `dtype`, sign-extended.
pub fn int_value(dtype: DataType, bytes: &[u8]) -> i64 {
    let mut b = [0u8; 8];
    let n = bytes.len().min(8);
    b[..n].copy_from_slice(&bytes[..n]);
    let u = u64::from_le_bytes(b);
    match (dtype.signed(), n) {
        (true, 1) => i64::from(u as u8 as i8),
        (true, 2) => i64::from(u as u16 as i16),
        (true, 4) => i64::from(u as u32 as i32),
        _ => u as i64,
    }
}

/// An object dictionary.
#[derive(Clone, Debug, Default)]
pub struct ObjectDictionary {
    entries: BTreeMap<(u16, u8), Entry>,
}

/// `true` for a PDO mapping parameter index (0x1600..=0x17FF RPDO, 0x1A00..=0x1BFF TPDO).
pub fn is_mapping_index(index: u16) -> bool {
    (0x1600..=0x17FF).contains(&index) || (0x1A00..=0x1BFF).contains(&index)
}

impl ObjectDictionary {
    /// An empty dictionary.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add (or replace) an entry with its initial value (an integer, stored in the type's
    /// size).
    pub fn add(
        &mut self,
        index: u16,
        sub: u8,
        dtype: DataType,
        access: Access,
        pdo_mappable: bool,
        value: i64,
    ) -> &mut Self {
        let size = dtype.size().unwrap_or(4);
        let bytes = value.to_le_bytes()[..size].to_vec();
        self.entries.insert(
            (index, sub),
            Entry {
                dtype,
                access,
                pdo_mappable,
                allowed: Allowed::Any,
                value: bytes,
            },
        );
        self
    }

    /// Add a variable-length entry (string or domain).
    pub fn add_bytes(
        &mut self,
        index: u16,
        sub: u8,
        dtype: DataType,
        access: Access,
        value: &[u8],
    ) {
        self.entries.insert(
            (index, sub),
            Entry {
                dtype,
                access,
                pdo_mappable: false,
                allowed: Allowed::Any,
                value: value.to_vec(),
            },
        );
    }

    /// Restrict the values the bus may write into an existing entry.
    pub fn restrict(&mut self, index: u16, sub: u8, allowed: Allowed) {
        if let Some(e) = self.entries.get_mut(&(index, sub)) {
            e.allowed = allowed;
        }
    }

    /// The entry at (index, sub).
    pub fn entry(&self, index: u16, sub: u8) -> Option<&Entry> {
        self.entries.get(&(index, sub))
    }

    fn lookup(&self, index: u16, sub: u8) -> Result<&Entry, AbortCode> {
        self.entries.get(&(index, sub)).ok_or_else(|| {
            if self
                .entries
                .range((index, 0)..=(index, 255))
                .next()
                .is_some()
            {
                AbortCode::NO_SUB_INDEX
            } else {
                AbortCode::NO_OBJECT
            }
        })
    }

    /// A read from the bus (SDO upload): the bytes, or the abort code.
    pub fn read(&self, index: u16, sub: u8) -> Result<&[u8], AbortCode> {
        let e = self.lookup(index, sub)?;
        if e.access == Access::Wo {
            return Err(AbortCode::WRITE_ONLY);
        }
        Ok(&e.value)
    }

    /// A write from the bus (SDO download or RPDO), checked as an SDO server checks it.
    pub fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        let e = self.lookup(index, sub)?;
        if matches!(e.access, Access::Ro | Access::Const) {
            return Err(AbortCode::READ_ONLY);
        }
        if let Some(size) = e.dtype.size() {
            if data.len() > size {
                return Err(AbortCode::LENGTH_TOO_HIGH);
            }
            if data.len() < size {
                return Err(AbortCode::LENGTH_TOO_LOW);
            }
            let v = int_value(e.dtype, data);
            match &e.allowed {
                Allowed::Any => {}
                Allowed::Range(lo, hi) => {
                    if v < *lo {
                        return Err(AbortCode::VALUE_TOO_LOW);
                    }
                    if v > *hi {
                        return Err(AbortCode::VALUE_TOO_HIGH);
                    }
                }
                Allowed::OneOf(list) => {
                    if !list.contains(&v) {
                        return Err(AbortCode::VALUE_RANGE);
                    }
                }
            }
        }
        if is_mapping_index(index) {
            self.check_mapping_write(index, sub, data)?;
        }
        self.set_bytes(index, sub, data);
        Ok(())
    }

    /// PDO mapping rules (CiA 301 §7.5.2.36): entries change only while sub 0 is 0; a non-zero
    /// sub 0 is accepted only when the mapped objects exist, are mappable and fit 64 bits.
    fn check_mapping_write(&self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        let count = self.u64(index, 0).unwrap_or(0);
        if sub != 0 {
            return if count == 0 {
                Ok(())
            } else {
                Err(AbortCode::WRONG_STATE)
            };
        }
        let n = int_value(DataType::U8, data) as u8;
        if n > 8 {
            return Err(AbortCode::VALUE_TOO_HIGH);
        }
        let mut bits = 0u32;
        for s in 1..=n {
            let m = self.u64(index, s).ok_or(AbortCode::NO_SUB_INDEX)? as u32;
            let (obj, osub, len) = ((m >> 16) as u16, (m >> 8) as u8, m & 0xFF);
            let target = self.entry(obj, osub).ok_or(AbortCode::NOT_MAPPABLE)?;
            let rx = index < 0x1A00;
            let ok_access = if rx {
                matches!(target.access, Access::Rw | Access::Wo)
            } else {
                target.access != Access::Wo
            };
            let size_bits = target.dtype.size().map_or(0, |s| 8 * s as u32);
            if !target.pdo_mappable || !ok_access || size_bits != len {
                return Err(AbortCode::NOT_MAPPABLE);
            }
            bits += len;
        }
        if bits > 64 {
            return Err(AbortCode::PDO_LENGTH);
        }
        Ok(())
    }

    /// Store bytes without the bus's checks (the node's own update of its values). Unknown
    /// entries are ignored.
    pub fn set_bytes(&mut self, index: u16, sub: u8, data: &[u8]) {
        if let Some(e) = self.entries.get_mut(&(index, sub)) {
            match e.dtype.size() {
                Some(size) => {
                    let n = data.len().min(size);
                    e.value[..n].copy_from_slice(&data[..n]);
                }
                None => e.value = data.to_vec(),
            }
        }
    }

    /// Store an integer without the bus's checks.
    pub fn set(&mut self, index: u16, sub: u8, value: i64) {
        self.set_bytes(index, sub, &value.to_le_bytes());
    }

    /// An integer entry's value, sign-extended (`None` when absent or not an integer).
    pub fn get(&self, index: u16, sub: u8) -> Option<i64> {
        let e = self.entries.get(&(index, sub))?;
        e.dtype.size()?;
        Some(int_value(e.dtype, &e.value))
    }

    fn u64(&self, index: u16, sub: u8) -> Option<u64> {
        self.get(index, sub).map(|v| v as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn od() -> ObjectDictionary {
        let mut od = ObjectDictionary::new();
        od.add(0x6040, 0, DataType::U16, Access::Rw, true, 0)
            .add(0x6041, 0, DataType::U16, Access::Ro, true, 0x40)
            .add(0x6060, 0, DataType::I8, Access::Rw, false, 10)
            .add(0x6071, 0, DataType::I16, Access::Rw, true, 0)
            .add(0x6064, 0, DataType::I32, Access::Ro, true, -5)
            .add(0x1600, 0, DataType::U8, Access::Rw, false, 0)
            .add(0x1A00, 0, DataType::U8, Access::Rw, false, 0);
        for s in 1..=8 {
            od.add(0x1600, s, DataType::U32, Access::Rw, false, 0);
            od.add(0x1A00, s, DataType::U32, Access::Rw, false, 0);
        }
        od.restrict(0x6060, 0, Allowed::OneOf(vec![4, 10]));
        od
    }

    #[test]
    fn writes_are_checked_like_an_sdo_server() {
        let mut od = od();
        assert_eq!(od.get(0x6064, 0), Some(-5));
        assert_eq!(od.read(0x6064, 0).unwrap(), &(-5i32).to_le_bytes());
        assert_eq!(od.write(0x6041, 0, &[0, 0]), Err(AbortCode::READ_ONLY));
        assert_eq!(od.write(0x6040, 0, &[6]), Err(AbortCode::LENGTH_TOO_LOW));
        assert_eq!(
            od.write(0x6040, 0, &[6, 0, 0]),
            Err(AbortCode::LENGTH_TOO_HIGH)
        );
        assert_eq!(od.write(0x6040, 1, &[6, 0]), Err(AbortCode::NO_SUB_INDEX));
        assert_eq!(od.write(0x6042, 0, &[6, 0]), Err(AbortCode::NO_OBJECT));
        assert_eq!(od.write(0x6060, 0, &[3]), Err(AbortCode::VALUE_RANGE));
        od.write(0x6060, 0, &[4]).unwrap();
        od.write(0x6071, 0, &(-300i16).to_le_bytes()).unwrap();
        assert_eq!(od.get(0x6071, 0), Some(-300));
    }

    #[test]
    fn pdo_mapping_rules() {
        let mut od = od();
        let map = |i: u16, s: u8, bits: u32| u32::from(i) << 16 | u32::from(s) << 8 | bits;
        od.write(0x1600, 1, &map(0x6040, 0, 16).to_le_bytes())
            .unwrap();
        od.write(0x1600, 2, &map(0x6071, 0, 16).to_le_bytes())
            .unwrap();
        od.write(0x1600, 0, &[2]).unwrap();
        // Entries are frozen while sub 0 is non-zero.
        assert_eq!(
            od.write(0x1600, 3, &map(0x6071, 0, 16).to_le_bytes()),
            Err(AbortCode::WRONG_STATE)
        );
        od.write(0x1600, 0, &[0]).unwrap();
        // A read-only object cannot be received; a non-mappable one not mapped at all; the
        // length must be the object's.
        od.write(0x1600, 3, &map(0x6041, 0, 16).to_le_bytes())
            .unwrap();
        assert_eq!(od.write(0x1600, 0, &[3]), Err(AbortCode::NOT_MAPPABLE));
        od.write(0x1A00, 1, &map(0x6060, 0, 8).to_le_bytes())
            .unwrap();
        assert_eq!(od.write(0x1A00, 0, &[1]), Err(AbortCode::NOT_MAPPABLE));
        od.write(0x1A00, 1, &map(0x6064, 0, 16).to_le_bytes())
            .unwrap();
        assert_eq!(od.write(0x1A00, 0, &[1]), Err(AbortCode::NOT_MAPPABLE));
        for s in 1..=3 {
            od.write(0x1A00, s, &map(0x6064, 0, 32).to_le_bytes())
                .unwrap();
        }
        assert_eq!(od.write(0x1A00, 0, &[3]), Err(AbortCode::PDO_LENGTH));
        od.write(0x1A00, 0, &[2]).unwrap();
    }
}
