//! The host link's transmit buffer: a byte ring that takes whole frames only.
//!
//! Producers queue encoded frames with [`TxRing::push_frame`], which refuses a frame that
//! does not fit (so a record the link cannot carry is dropped whole and counted by the
//! caller, never cut); the UART interrupt takes bytes out with [`TxRing::pop`]. [`TxLink`]
//! adds the frame sequence number, so that frames queued by several tasks keep their
//! numbers in order.

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

/// What [`TxLink::queue`] did with a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Queued {
    /// Queued whole; the sequence number moved on.
    Queued,
    /// Not enough room: nothing queued, the sequence number unchanged.
    NoRoom,
    /// The frame carries an old sequence number (another frame went first): encode it
    /// again with [`TxLink::next_seq`].
    Stale,
}

/// The host link's transmit side: the byte ring and the next frame's sequence number.
pub struct TxLink<const N: usize> {
    ring: TxRing<N>,
    next_seq: u32,
}

impl<const N: usize> Default for TxLink<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> TxLink<N> {
    /// An empty ring; the first frame gets sequence number 0.
    pub const fn new() -> Self {
        Self {
            ring: TxRing::new(),
            next_seq: 0,
        }
    }

    /// Sequence number of the next frame.
    pub fn next_seq(&self) -> u32 {
        self.next_seq
    }

    /// The byte ring (the UART interrupt takes bytes from it).
    pub fn ring(&mut self) -> &mut TxRing<N> {
        &mut self.ring
    }

    /// Queues `frame`, encoded with sequence number `seq`, whole if it fits with `reserve`
    /// bytes to spare.
    pub fn queue(&mut self, seq: u32, frame: &[u8], reserve: usize) -> Queued {
        if self.next_seq != seq {
            Queued::Stale
        } else if self.ring.push_frame(frame, reserve) {
            self.next_seq = seq.wrapping_add(1);
            Queued::Queued
        } else {
            Queued::NoRoom
        }
    }

    /// Queues `frame`, a frame of another protocol (MAVLink) that has no sequence number of
    /// ours, whole if it fits with `reserve` bytes to spare; false when it did not fit.
    pub fn queue_raw(&mut self, frame: &[u8], reserve: usize) -> bool {
        self.ring.push_frame(frame, reserve)
    }
}
