//! Keys of the robot link: the pre-shared key ([`Psk`], `exompc keygen`), the handshake key
//! derived from it, the session key derived from it and both sides' fresh nonces, and the MAC
//! ([`Key::mac`], keyed BLAKE3 from the `blake3` crate). [`super::frame`] signs and checks frames
//! with these keys; [`super::session`] runs the handshake.

/// Nonce length (bytes).
pub const NONCE_LEN: usize = 32;
/// Shortest pre-shared key accepted (bytes).
pub const MIN_KEY_LEN: usize = 32;
/// Longest pre-shared key accepted (bytes).
pub const MAX_KEY_LEN: usize = 4096;

use alloc::vec::Vec;

const HANDSHAKE_CONTEXT: &str = "exompc 2026-12-03 robot link v2 handshake key";
const SESSION_CONTEXT: &str = "exompc 2026-12-03 robot link v2 session key";

/// A 256-bit MAC key (the handshake key or a session key). Its `Debug` shows no key bytes.
#[derive(Clone, PartialEq, Eq)]
pub struct Key([u8; 32]);

impl core::fmt::Debug for Key {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Key(..)")
    }
}

impl Key {
    /// A key from raw bytes.
    pub fn from_bytes(b: [u8; 32]) -> Self {
        Key(b)
    }

    /// The MAC of `data`: keyed BLAKE3, 32 bytes.
    pub fn mac(&self, data: &[u8]) -> [u8; 32] {
        *blake3::keyed_hash(&self.0, data).as_bytes()
    }

    /// Whether `tag` is the MAC of `data` (constant-time comparison).
    pub fn verify(&self, data: &[u8], tag: &[u8]) -> bool {
        let Ok(t) = <[u8; 32]>::try_from(tag) else {
            return false;
        };
        blake3::keyed_hash(&self.0, data) == blake3::Hash::from_bytes(t)
    }
}

/// Why a key is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// Fewer than [`MIN_KEY_LEN`] bytes (after trailing whitespace) or more than
    /// [`MAX_KEY_LEN`].
    #[error(
        "key of {0} bytes: allowed {MIN_KEY_LEN} to {MAX_KEY_LEN} bytes (exompc keygen writes one)"
    )]
    Length(usize),
}

/// The pre-shared key of a controller and its robot: the bytes of the key file, trailing ASCII
/// whitespace removed (`exompc keygen` writes 32 random bytes as 64 hex digits and a newline).
#[derive(Clone, PartialEq, Eq)]
pub struct Psk {
    bytes: Vec<u8>,
    handshake: Key,
}

impl core::fmt::Debug for Psk {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Psk({} bytes)", self.bytes.len())
    }
}

impl Psk {
    /// The key of a key file's contents.
    pub fn new(contents: &[u8]) -> Result<Self, KeyError> {
        let end = contents
            .iter()
            .rposition(|b| !b.is_ascii_whitespace())
            .map_or(0, |i| i + 1);
        let bytes = &contents[..end];
        if !(MIN_KEY_LEN..=MAX_KEY_LEN).contains(&bytes.len()) {
            return Err(KeyError::Length(bytes.len()));
        }
        Ok(Psk {
            bytes: bytes.to_vec(),
            handshake: Key(blake3::derive_key(HANDSHAKE_CONTEXT, bytes)),
        })
    }

    /// The contents of a fresh key file: 32 bytes from the OS's random source, as 64 lowercase
    /// hex digits and a newline.
    #[cfg(feature = "std")]
    pub fn generate_file() -> std::io::Result<String> {
        let mut b = [0u8; 32];
        getrandom::fill(&mut b).map_err(std::io::Error::other)?;
        let mut s = String::with_capacity(65);
        for x in b {
            s.push_str(&format!("{x:02x}"));
        }
        s.push('\n');
        Ok(s)
    }

    /// The key of hello and challenge frames.
    pub fn handshake_key(&self) -> &Key {
        &self.handshake
    }

    /// The session key of the handshake with controller nonce `nonce_c` and robot nonce
    /// `nonce_r` (BLAKE3 in key-derivation mode over the PSK and both nonces).
    pub fn session_key(&self, nonce_c: &[u8; NONCE_LEN], nonce_r: &[u8; NONCE_LEN]) -> Key {
        let mut h = blake3::Hasher::new_derive_key(SESSION_CONTEXT);
        h.update(&(self.bytes.len() as u64).to_le_bytes());
        h.update(&self.bytes);
        h.update(nonce_c);
        h.update(nonce_r);
        Key(*h.finalize().as_bytes())
    }
}

/// A fresh nonce from the OS's random source.
#[cfg(feature = "std")]
pub fn random_nonce() -> std::io::Result<[u8; NONCE_LEN]> {
    let mut n = [0u8; NONCE_LEN];
    getrandom::fill(&mut n).map_err(std::io::Error::other)?;
    Ok(n)
}
