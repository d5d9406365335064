//! Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999).
//!
//! COBS rewrites a block so that it contains no 0x00 byte, at a cost of at most one byte per
//! 254 bytes plus one: the 0x00 byte is then free to delimit frames on the wire. Each encoded
//! group starts with a code byte `n` (1..=255): `n - 1` data bytes follow, and, unless
//! `n == 255` or the group is the last one, a 0x00 byte is implied after them.

/// Largest encoded size of `len` raw bytes (without the 0x00 delimiter).
pub const fn max_encoded_len(len: usize) -> usize {
    len + len / 254 + 1
}

/// Why a COBS operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CobsError {
    /// The output buffer is too small.
    BufferTooSmall,
    /// The input is not valid COBS (a 0x00 byte, or a code byte pointing past the end).
    Malformed,
}

/// Encodes `src` into `dst` (no delimiter is written); returns the encoded length.
pub fn encode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    if dst.len() < max_encoded_len(src.len()) {
        return Err(CobsError::BufferTooSmall);
    }
    let mut code_pos = 0;
    let mut out = 1;
    let mut code: u8 = 1;
    for &b in src {
        if b == 0 {
            dst[code_pos] = code;
            code_pos = out;
            out += 1;
            code = 1;
        } else {
            dst[out] = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                dst[code_pos] = code;
                code_pos = out;
                out += 1;
                code = 1;
            }
        }
    }
    dst[code_pos] = code;
    Ok(out)
}

/// Decodes the COBS block `buf` (without its delimiter) in place; returns the decoded length.
/// The decoded bytes occupy `buf[..len]`.
pub fn decode_in_place(buf: &mut [u8]) -> Result<usize, CobsError> {
    let n = buf.len();
    let mut read = 0;
    let mut write = 0;
    while read < n {
        let code = buf[read] as usize;
        if code == 0 {
            return Err(CobsError::Malformed);
        }
        read += 1;
        let end = read + code - 1;
        if end > n {
            return Err(CobsError::Malformed);
        }
        while read < end {
            let b = buf[read];
            if b == 0 {
                return Err(CobsError::Malformed);
            }
            buf[write] = b;
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < n {
            buf[write] = 0;
            write += 1;
        }
    }
    Ok(write)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_vectors() {
        let cases: &[(&[u8], &[u8])] = &[
            (&[], &[0x01]),
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
        ];
        for (raw, enc) in cases {
            let mut buf = [0u8; 16];
            let n = encode(raw, &mut buf).unwrap();
            assert_eq!(&buf[..n], *enc);
            let m = decode_in_place(&mut buf[..n]).unwrap();
            assert_eq!(&buf[..m], *raw);
        }
    }

    #[test]
    fn long_runs() {
        for len in [253usize, 254, 255, 508, 509, 600] {
            let raw: std::vec::Vec<u8> = (0..len).map(|i| (i % 255 + 1) as u8).collect();
            let mut enc = std::vec![0u8; max_encoded_len(len)];
            let n = encode(&raw, &mut enc).unwrap();
            assert!(enc[..n].iter().all(|&b| b != 0));
            let m = decode_in_place(&mut enc[..n]).unwrap();
            assert_eq!(&enc[..m], &raw[..]);
        }
    }
}
