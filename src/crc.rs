//! CRC-32/ISO-HDLC (the CRC of Ethernet, zlib, PNG), driven by a `const`-built table of the
//! 16 nibbles (64 bytes of flash instead of the 1 KiB of a byte table, for two lookups per
//! byte instead of one).
//!
//! Parameters (Rocksoft/Williams model, as in the CRC catalogue):
//! width 32, poly `0x04C11DB7`, init `0xFFFFFFFF`, refin true, refout true,
//! xorout `0xFFFFFFFF`, check (CRC of ASCII `123456789`) `0xCBF43926`.
//! Reflected, the polynomial is `0xEDB88320`.

/// Reflected generator polynomial of CRC-32/ISO-HDLC.
const POLY_REFLECTED: u32 = 0xEDB8_8320;

/// Entry `n`: the register contribution of the low nibble `n` shifted out (four steps).
const fn make_table() -> [u32; 16] {
    let mut table = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 4 {
            c = if c & 1 != 0 {
                (c >> 1) ^ POLY_REFLECTED
            } else {
                c >> 1
            };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
}

static TABLE: [u32; 16] = make_table();

/// Incremental CRC-32/ISO-HDLC: `Crc32::new()`, any number of [`Crc32::update`], then
/// [`Crc32::finish`].
#[derive(Debug, Clone, Copy)]
pub struct Crc32 {
    state: u32,
}

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// A CRC in its initial state (`init = 0xFFFFFFFF`).
    pub const fn new() -> Self {
        Self { state: 0xFFFF_FFFF }
    }

    /// Feeds bytes.
    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.state;
        for &b in bytes {
            c ^= u32::from(b);
            c = TABLE[(c & 0xF) as usize] ^ (c >> 4);
            c = TABLE[(c & 0xF) as usize] ^ (c >> 4);
        }
        self.state = c;
    }

    /// The CRC of everything fed so far (`xorout = 0xFFFFFFFF` applied).
    pub fn finish(&self) -> u32 {
        self.state ^ 0xFFFF_FFFF
    }
}

/// CRC-32/ISO-HDLC of `bytes` in one call.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut c = Crc32::new();
    c.update(bytes);
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    /// The definition, one bit at a time.
    fn bitwise(bytes: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    (c >> 1) ^ POLY_REFLECTED
                } else {
                    c >> 1
                };
            }
        }
        c ^ 0xFFFF_FFFF
    }

    #[test]
    fn table_matches_the_bitwise_definition_and_splits_freely() {
        // Every single byte, and a pseudo-random stream (xorshift) of every length to 300,
        // fed whole and in two parts at every split.
        for b in 0..=255u8 {
            assert_eq!(crc32(&[b]), bitwise(&[b]), "{b:#04x}");
        }
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let data: [u8; 300] = core::array::from_fn(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 32) as u8
        });
        for n in 0..=data.len() {
            let whole = crc32(&data[..n]);
            assert_eq!(whole, bitwise(&data[..n]), "length {n}");
            for split in [0, n / 3, n / 2, n] {
                let mut c = Crc32::new();
                c.update(&data[..split]);
                c.update(&data[split..n]);
                assert_eq!(c.finish(), whole, "length {n}, split {split}");
            }
        }
    }
}
