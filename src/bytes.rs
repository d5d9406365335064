//! Little-endian field writer and reader over caller buffers, and [`Text`] (crate-internal).

/// A `&str` as a format argument, written as it is: `{}` of a plain `&str` links core's
/// `Formatter::pad` (width and precision handling, about 500 bytes of flash) that the
/// firmware never uses.
#[derive(Clone, Copy)]
pub(crate) struct Text<'a>(pub(crate) &'a str);

impl core::fmt::Display for Text<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.0)
    }
}

/// The buffer ended before the field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct OutOfSpace;

/// Writes fixed little-endian fields into a slice. Its methods are always inlined: with
/// `opt-level = "z"` a call per field costs more flash (184 bytes in all) and time (about 700
/// instructions per pose frame) than the inlined copy.
pub(crate) struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    pub(crate) fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    pub(crate) fn pos(&self) -> usize {
        self.pos
    }
    #[inline(always)]
    pub(crate) fn bytes(&mut self, b: &[u8]) -> Result<(), OutOfSpace> {
        let end = self.pos.checked_add(b.len()).ok_or(OutOfSpace)?;
        let dst = self.buf.get_mut(self.pos..end).ok_or(OutOfSpace)?;
        dst.copy_from_slice(b);
        self.pos = end;
        Ok(())
    }
    #[inline(always)]
    pub(crate) fn u8(&mut self, v: u8) -> Result<(), OutOfSpace> {
        self.bytes(&[v])
    }
    #[inline(always)]
    pub(crate) fn u16(&mut self, v: u16) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_le_bytes())
    }
    #[inline(always)]
    pub(crate) fn u32(&mut self, v: u32) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_le_bytes())
    }
    #[inline(always)]
    pub(crate) fn u64(&mut self, v: u64) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_le_bytes())
    }
    #[inline(always)]
    pub(crate) fn i64(&mut self, v: i64) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_le_bytes())
    }
    #[inline(always)]
    pub(crate) fn f32(&mut self, v: f32) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_bits().to_le_bytes())
    }
    #[inline(always)]
    pub(crate) fn f64(&mut self, v: f64) -> Result<(), OutOfSpace> {
        self.bytes(&v.to_bits().to_le_bytes())
    }
}

/// Reads fixed little-endian fields from a slice (methods always inlined, as [`Writer`]'s:
/// 256 bytes less flash).
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    #[inline(always)]
    pub(crate) fn bytes(&mut self, n: usize) -> Result<&'a [u8], OutOfSpace> {
        let end = self.pos.checked_add(n).ok_or(OutOfSpace)?;
        let s = self.buf.get(self.pos..end).ok_or(OutOfSpace)?;
        self.pos = end;
        Ok(s)
    }
    #[inline(always)]
    fn array<const N: usize>(&mut self) -> Result<[u8; N], OutOfSpace> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.bytes(N)?);
        Ok(a)
    }
    #[inline(always)]
    pub(crate) fn u8(&mut self) -> Result<u8, OutOfSpace> {
        Ok(self.array::<1>()?[0])
    }
    #[inline(always)]
    pub(crate) fn u16(&mut self) -> Result<u16, OutOfSpace> {
        Ok(u16::from_le_bytes(self.array()?))
    }
    #[inline(always)]
    pub(crate) fn u32(&mut self) -> Result<u32, OutOfSpace> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    #[inline(always)]
    pub(crate) fn u64(&mut self) -> Result<u64, OutOfSpace> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    #[inline(always)]
    pub(crate) fn i64(&mut self) -> Result<i64, OutOfSpace> {
        Ok(i64::from_le_bytes(self.array()?))
    }
    #[inline(always)]
    pub(crate) fn f32(&mut self) -> Result<f32, OutOfSpace> {
        Ok(f32::from_bits(u32::from_le_bytes(self.array()?)))
    }
    #[inline(always)]
    pub(crate) fn f64(&mut self) -> Result<f64, OutOfSpace> {
        Ok(f64::from_bits(u64::from_le_bytes(self.array()?)))
    }
}
