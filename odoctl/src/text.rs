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

/// At most [`EXCERPT_CHARS`] characters of text quoting `s`, escapes included: printable
/// characters as they are, `\` as `\\`, control characters and a byte-order mark as `\xNN`
/// (their UTF-8 bytes), U+FFFD (a byte that was not UTF-8, in lossily read text) as
/// `\u{FFFD}`; `...` follows when cut.
pub fn excerpt(s: &str) -> String {
    excerpt_n(s, EXCERPT_CHARS)
}

/// [`excerpt`] of at most `max` characters (a library's error message that quotes input).
pub fn excerpt_n(s: &str, max: usize) -> String {
    let mut out = Quote::new(max);
    for c in s.chars() {
        if !out.push(&escaped(c)) {
            break;
        }
    }
    out.text
}

/// [`excerpt`] of bytes: valid UTF-8 as text, other bytes as `\xNN`.
pub fn excerpt_bytes(b: &[u8]) -> String {
    let mut out = Quote::new(EXCERPT_CHARS);
    for chunk in b.utf8_chunks() {
        for c in chunk.valid().chars() {
            if !out.push(&escaped(c)) {
                return out.text;
            }
        }
        for byte in chunk.invalid() {
            if !out.push(&format!("\\x{byte:02X}")) {
                return out.text;
            }
        }
    }
    out.text
}

/// An excerpt being built: its text and how many characters it may still take.
struct Quote {
    text: String,
    left: usize,
}

impl Quote {
    fn new(max: usize) -> Self {
        Self {
            text: String::new(),
            left: max,
        }
    }

    /// Appends `piece` when it fits, else `...`; false once cut.
    fn push(&mut self, piece: &str) -> bool {
        let n = piece.chars().count();
        if n > self.left {
            self.text.push_str("...");
            self.left = 0;
            return false;
        }
        self.text.push_str(piece);
        self.left -= n;
        true
    }
}

fn escaped(c: char) -> String {
    match c {
        '\\' => "\\\\".to_string(),
        '\u{fffd}' => "\\u{FFFD}".to_string(),
        c if c.is_control() || c == '\u{feff}' => {
            let mut buf = [0u8; 4];
            c.encode_utf8(&mut buf)
                .bytes()
                .map(|b| format!("\\x{b:02X}"))
                .collect()
        }
        c => c.to_string(),
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
        assert_eq!(excerpt("\u{fffd}"), "\\u{FFFD}");
        assert_eq!(excerpt("\u{feff}t"), "\\xEF\\xBB\\xBFt");
        let long = "x".repeat(2000);
        assert_eq!(excerpt(&long), format!("{}...", "x".repeat(EXCERPT_CHARS)));
        assert_eq!(excerpt_bytes(b"\xb5b\x01\x07ok"), "\\xB5b\\x01\\x07ok");
        let bin: Vec<u8> = (0..=255u8).cycle().take(2048).collect();
        let e = excerpt_bytes(&bin);
        assert!(e.chars().count() <= EXCERPT_CHARS + 3, "{e}");
        let e = excerpt(&"\u{fffd}".repeat(100));
        assert!(e.chars().count() <= EXCERPT_CHARS + 3, "{e}");
        assert!(e.bytes().all(|b| (b' '..=b'~').contains(&b)), "{e}");
    }
}
