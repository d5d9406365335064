//! The host link's transmit buffer: a byte ring that takes whole frames only.
//!
//! Producers queue encoded frames with [`TxRing::push_frame`], which refuses a frame that
//! does not fit (so a record the link cannot carry is dropped whole and counted by the
//! caller, never cut); the UART interrupt takes bytes out with [`TxRing::pop`].

/// A byte ring of `N` bytes holding whole frames.
pub struct TxRing<const N: usize> {
    buf: [u8; N],
    head: usize,
    len: usize,
}

impl<const N: usize> Default for TxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> TxRing<N> {
    /// An empty ring.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            head: 0,
            len: 0,
        }
    }

    /// Free bytes.
    pub fn free(&self) -> usize {
        N - self.len
    }

    /// Appends `frame` whole if it fits in the free space less `reserve`; false otherwise
    /// (nothing is written).
    pub fn push_frame(&mut self, frame: &[u8], reserve: usize) -> bool {
        if frame.len() + reserve > self.free() {
            return false;
        }
        let tail = (self.head + self.len) % N;
        let first = frame.len().min(N - tail);
        self.buf[tail..tail + first].copy_from_slice(&frame[..first]);
        self.buf[..frame.len() - first].copy_from_slice(&frame[first..]);
        self.len += frame.len();
        true
    }

    /// Takes the oldest byte.
    pub fn pop(&mut self) -> Option<u8> {
        if self.len == 0 {
            return None;
        }
        let b = self.buf[self.head];
        self.head = (self.head + 1) % N;
        self.len -= 1;
        Some(b)
    }

    /// True when no byte waits.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}
