//! Text as files hold it: lines ended by CR LF, LF or CR alone ([`lines`]), and short escaped
//! excerpts of input for error messages ([`excerpt`], [`excerpt_bytes`]), so that binary data
//! given where text is expected never floods a terminal.

/// The most characters of input an error message quotes.
pub const EXCERPT_CHARS: usize = 40;

/// The lines of `text`, numbered from 1; a line ends at CR LF, LF or a CR alone (a receiver
/// log written with carriage returns only), and the ending is not part of it.
pub fn lines(text: &str) -> Lines<'_> {
    Lines { rest: text, n: 0 }
}

/// The iterator of [`lines`]: `(1-based line number, line)`.
#[derive(Debug, Clone)]
pub struct Lines<'a> {
    rest: &'a str,
    n: usize,
}

impl<'a> Iterator for Lines<'a> {
    type Item = (usize, &'a str);

    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        let bytes = self.rest.as_bytes();
        let (line, rest) = match bytes.iter().position(|&b| b == b'\r' || b == b'\n') {
            None => (self.rest, ""),
            Some(i) => {
                let end = if bytes[i] == b'\r' && bytes.get(i + 1) == Some(&b'\n') {
                    i + 2
                } else {
                    i + 1
                };
                (&self.rest[..i], &self.rest[end..])
            }
        };
        self.rest = rest;
        self.n += 1;
        Some((self.n, line))
    }
}

/// At most [`EXCERPT_CHARS`] characters of `s`, printable ASCII and other printable
/// characters as they are, control characters, U+FFFD and other non-printables as `\xNN`
/// (their UTF-8 bytes), and `...` when cut.
pub fn excerpt(s: &str) -> String {
    excerpt_n(s, EXCERPT_CHARS)
}

/// [`excerpt`] of at most `max` characters (a library's error message that quotes input).
pub fn excerpt_n(s: &str, max: usize) -> String {
    let mut out = String::new();
    for (n, c) in s.chars().enumerate() {
        if n == max {
            out.push_str("...");
            break;
        }
        push_char(&mut out, c);
    }
    out
}

/// [`excerpt`] of bytes: valid UTF-8 as text, other bytes as `\xNN`.
pub fn excerpt_bytes(b: &[u8]) -> String {
    let mut out = String::new();
    let mut n = 0;
    for chunk in b.utf8_chunks() {
        for c in chunk.valid().chars() {
            if n == EXCERPT_CHARS {
                out.push_str("...");
                return out;
            }
            push_char(&mut out, c);
            n += 1;
        }
        for byte in chunk.invalid() {
            if n == EXCERPT_CHARS {
                out.push_str("...");
                return out;
            }
            out.push_str(&format!("\\x{byte:02X}"));
            n += 1;
        }
    }
    out
}

fn push_char(out: &mut String, c: char) {
    if c == '\\' {
        out.push_str("\\\\");
    } else if c.is_control() || c == '\u{fffd}' || c == '\u{feff}' {
        let mut buf = [0u8; 4];
        for b in c.encode_utf8(&mut buf).bytes() {
            out.push_str(&format!("\\x{b:02X}"));
        }
    } else {
        out.push(c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_endings() {
        let table: [(&str, &[(usize, &str)]); 7] = [
            ("", &[]),
            ("a", &[(1, "a")]),
            ("a\nb\n", &[(1, "a"), (2, "b")]),
            ("a\r\nb\r\n", &[(1, "a"), (2, "b")]),
            ("a\rb\r", &[(1, "a"), (2, "b")]),
            ("a\r\rb", &[(1, "a"), (2, ""), (3, "b")]),
            ("a\n\r\nb\rc", &[(1, "a"), (2, ""), (3, "b"), (4, "c")]),
        ];
        for (text, want) in table {
            let got: Vec<(usize, &str)> = lines(text).collect();
            assert_eq!(got, want, "{text:?}");
        }
    }

    #[test]
    fn excerpts_are_short_and_escaped() {
        assert_eq!(excerpt("abc"), "abc");
        assert_eq!(excerpt("a\u{1}\tb\\"), "a\\x01\\x09b\\\\");
        assert_eq!(excerpt("\u{fffd}"), "\\xEF\\xBF\\xBD");
        let long = "x".repeat(2000);
        assert_eq!(excerpt(&long), format!("{}...", "x".repeat(EXCERPT_CHARS)));
        assert_eq!(excerpt_bytes(b"\xb5b\x01\x07ok"), "\\xB5b\\x01\\x07ok");
        let bin: Vec<u8> = (0..=255u8).cycle().take(2048).collect();
        let e = excerpt_bytes(&bin);
        assert!(e.len() <= 4 * EXCERPT_CHARS + 3, "{e}");
        assert!(e.bytes().all(|b| (b' '..=b'~').contains(&b)), "{e}");
    }
}
