//! The link to the unit: a serial port (`serialport`, no libudev) or a TCP socket
//! (`tcp:HOST:PORT`, the QEMU image's USART2), framed by the core's protocol code
//! (`odo_unit::protocol`: COBS frames with CRC-32, `FrameDecoder` with loss accounting).
//!
//! A [`Session`] reads and decodes the unit's frames, keeps the health counters
//! ([`StreamStats`], [`health`]) and sends command lines; [`SegmentWriter`] writes the pose
//! records as SAMPLES CSV, one file per segment of increasing time, live (`record`) or from a
//! capture ([`decode_bytes`]). The commands `monitor`, `record`, `decode`, `config` and
//! `bridge` are built on it.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufWriter, ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use odo_unit::protocol::{DecoderStats, Frame, FrameDecoder, Message, PoseRecord, Status};
use odo_unit::timing::SyncState;

use crate::csvio::{RecordFields, Sample, SamplesLayout, UnitPose};

/// A byte stream to the unit.
pub trait Link: Read + Write + Send {}
impl<T: Read + Write + Send> Link for T {}

/// How long the first command of a session waits for the unit's first frame.
pub const ALIVE_WAIT: Duration = Duration::from_secs(3);

/// Read timeout of one poll.
const POLL: Duration = Duration::from_millis(50);

/// Opens `port`: `tcp:HOST:PORT` or a serial device at `baud`.
pub fn open(port: &str, baud: u32) -> Result<Box<dyn Link>> {
    if let Some(addr) = port.strip_prefix("tcp:") {
        let s = TcpStream::connect(addr).with_context(|| format!("{port}: cannot connect"))?;
        s.set_read_timeout(Some(POLL))?;
        s.set_nodelay(true)?;
        Ok(Box::new(s))
    } else {
        let p = serialport::new(port, baud)
            .timeout(POLL)
            .open()
            .with_context(|| format!("{port}: cannot open serial port"))?;
        Ok(Box::new(p))
    }
}

/// Record-level accounting on top of the decoder's frame counters.
#[derive(Debug, Clone, Default)]
pub struct StreamStats {
    /// Pose records received.
    pub records: u64,
    /// Sum of the records' `dropped` fields: records the unit could not send.
    pub dropped_by_unit: u64,
    /// Times the record sequence did not advance by the usual step (records lost on the link
    /// or dropped by the unit).
    pub record_gaps: u64,
    /// Usual sequence step between records (the unit's `output_divider`).
    pub step: Option<u32>,
    last_seq: Option<u32>,
}

impl StreamStats {
    fn on_record(&mut self, r: &PoseRecord) {
        self.records += 1;
        self.dropped_by_unit += u64::from(r.dropped);
        if let Some(last) = self.last_seq {
            let d = r.sequence.wrapping_sub(last);
            match self.step {
                None => self.step = Some(d.max(1)),
                Some(s) if d != s => self.record_gaps += 1,
                _ => {}
            }
        }
        self.last_seq = Some(r.sequence);
    }
}

/// Formats the link's health: frame counters of the decoder and record counters.
pub fn health(d: &DecoderStats, s: &StreamStats) -> String {
    format!(
        "frames {}, joined after {} bytes, CRC errors {}, malformed {}, oversize {}, version errors {}, unknown types {}, frame sequence gaps {} ({} frames lost); records {}, record sequence gaps {}, dropped by the unit {}",
        d.frames,
        d.join_bytes,
        d.crc_errors,
        d.malformed,
        d.oversize,
        d.version_errors,
        d.unknown_type,
        d.seq_gaps,
        d.frames_lost,
        s.records,
        s.record_gaps,
        s.dropped_by_unit
    )
}

/// A session with the unit: reads bytes, decodes frames, sends command lines.
pub struct Session {
    link: Box<dyn Link>,
    decoder: FrameDecoder,
    pending: VecDeque<Frame>,
    raw: Option<BufWriter<File>>,
    eof: bool,
    alive: bool,
    /// Record-level counters (updated as frames are taken with [`Session::next_frame`]).
    pub stats: StreamStats,
}

impl Session {
    /// A session over `link`, keeping a copy of every received byte in `raw` if given.
    pub fn new(link: Box<dyn Link>, raw: Option<&Path>) -> Result<Self> {
        let raw = match raw {
            Some(p) => {
                Some(BufWriter::new(File::create(p).with_context(|| {
                    format!("{}: cannot create", p.display())
                })?))
            }
            None => None,
        };
        Ok(Self {
            link,
            decoder: FrameDecoder::new(),
            pending: VecDeque::new(),
            raw,
            eof: false,
            alive: false,
            stats: StreamStats::default(),
        })
    }

    /// The decoder's counters.
    pub fn decoder_stats(&self) -> DecoderStats {
        self.decoder.stats()
    }

    /// True once the other end closed the connection.
    pub fn closed(&self) -> bool {
        self.eof
    }

    fn pump(&mut self) -> Result<()> {
        let mut buf = [0u8; 4096];
        match self.link.read(&mut buf) {
            Ok(0) => self.eof = true,
            Ok(n) => {
                if let Some(r) = &mut self.raw {
                    r.write_all(&buf[..n])?;
                }
                let pending = &mut self.pending;
                self.decoder.feed(&buf[..n], |f| {
                    if let Ok(f) = f {
                        pending.push_back(f);
                    }
                });
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) => {}
            // As a message, not an io::Error source: a BrokenPipe here is a lost link, not
            // the closed stdout that `main` lets pass silently.
            Err(e) => bail!("the link to the unit failed while reading: {e}"),
        }
        Ok(())
    }

    /// The next decoded frame, waiting until `deadline`; `None` at the deadline or when the
    /// link closed.
    pub fn next_frame(&mut self, deadline: Option<Instant>) -> Result<Option<Frame>> {
        loop {
            if let Some(f) = self.pending.pop_front() {
                if let Message::Pose(r) = &f.message {
                    self.stats.on_record(r);
                }
                return Ok(Some(f));
            }
            if self.eof || deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(None);
            }
            self.pump()?;
        }
    }

    /// Sends one command line. A failed write (the unit closed the link) is an error
    /// naming the line, as a message (see [`Session::pump`]).
    pub fn send_line(&mut self, line: &str) -> Result<()> {
        let mut bytes = Vec::with_capacity(line.len() + 1);
        bytes.extend_from_slice(line.as_bytes());
        bytes.push(b'\n');
        self.link
            .write_all(&bytes)
            .and_then(|()| self.link.flush())
            .map_err(|e| anyhow!("`{line}` not sent: the link to the unit is lost ({e})"))
    }

    /// Sends `line` and collects its reply (all frames until one without `more`); other
    /// frames arriving meanwhile are passed to `other`. Returns (ok, text).
    ///
    /// Before the first command of a session it waits (up to [`ALIVE_WAIT`]) for the unit's
    /// first frame, so a unit that is still booting (the QEMU image starts when the socket
    /// connects) does not miss the line.
    pub fn command_with(
        &mut self,
        line: &str,
        timeout: Duration,
        mut other: impl FnMut(&Frame),
    ) -> Result<(bool, String)> {
        if !self.alive {
            self.alive = true;
            let deadline = Instant::now() + ALIVE_WAIT;
            while self.pending.is_empty() && !self.eof && Instant::now() < deadline {
                self.pump()?;
            }
        }
        self.send_line(line)?;
        let deadline = Instant::now() + timeout;
        let mut text = String::new();
        let mut ok = None;
        loop {
            let Some(f) = self.next_frame(Some(deadline))? else {
                if self.eof {
                    bail!("`{line}`: the unit closed the connection before replying");
                }
                bail!("`{line}`: no reply within {} s", timeout.as_secs_f64());
            };
            match &f.message {
                Message::Reply(r) => {
                    ok.get_or_insert(r.ok);
                    text.push_str(&r.text);
                    if !r.more {
                        return Ok((ok.unwrap_or(false), text));
                    }
                }
                _ => other(&f),
            }
        }
    }

    /// [`Session::command_with`], discarding other frames.
    pub fn command(&mut self, line: &str, timeout: Duration) -> Result<(bool, String)> {
        self.command_with(line, timeout, |_| {})
    }

    /// Flushes the raw capture.
    pub fn finish(&mut self) -> Result<()> {
        if let Some(r) = &mut self.raw {
            r.flush()?;
        }
        Ok(())
    }
}

/// How long a command line waits for the unit's reply.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

fn sync_name(m: SyncState) -> &'static str {
    match m {
        SyncState::FreeRunning => "free",
        SyncState::Locked => "pps",
        SyncState::Holdover => "hold",
    }
}

/// One line of the human table of `monitor`.
pub fn table_row(r: &PoseRecord) -> String {
    let wheel = |w: &odo_unit::protocol::WheelStatus| {
        format!(
            "{}{}{}{}",
            if w.fault { 'F' } else { '-' },
            if w.index_seen { 'I' } else { '-' },
            if w.index_mismatch { 'M' } else { '-' },
            if w.calibrated { 'C' } else { '-' }
        )
    };
    format!(
        "{:>9} {:>11.3} {:>10.4} {:>10.4} {:>9.3} {:>8.2} {:>8.2} {:>7.3} {:>11} {:>11} {:>4} {} {} {:>4}",
        r.sequence,
        r.mcu_time_us as f64 * 1e-6,
        r.x,
        r.y,
        r.heading.to_degrees(),
        f64::from(r.sigma_x) * 1e3,
        f64::from(r.sigma_y) * 1e3,
        f64::from(r.sigma_heading).to_degrees(),
        r.gamma_left,
        r.gamma_right,
        sync_name(r.flags.sync),
        wheel(&r.flags.left),
        wheel(&r.flags.right),
        r.dropped
    )
}

/// Header of the human table.
pub const TABLE_HEADER: &str =
    "      seq    mcu t[s]      x [m]      y [m] head[deg]  sx [mm]  sy [mm] sh[deg]        left       right sync L    R    drop";

/// One comment line (`# status: ...`, `# device: ...`, `# reply: ...`) for a frame other than a
/// pose record; `None` for a pose record.
pub fn describe(f: &Frame) -> Option<String> {
    match &f.message {
        Message::Status(s) => Some(format!(
            "# status: uptime {:.1} s, rate {} Hz / output_divider {}, sync {}, samples {}, dropped {}, samples lost {}, merged {}, PPS edges {} (rejected {}), index lost {}, host rx lost {} (overruns {}, line errors {}), GNSS rx lost {} (overruns {}, line errors {}), GNSS sentences forwarded {} (not forwarded {}, bad checksum {}, overlong {}), reset cause {}, settings {:?}{}",
            s.uptime_us as f64 * 1e-6,
            s.rate_hz,
            s.output_divider,
            sync_name(s.flags.sync),
            s.samples,
            s.dropped_total,
            s.samples_lost,
            s.merged_samples,
            s.pps_edges,
            s.pps_rejected,
            s.index_lost,
            s.host_rx_lost,
            s.host_rx_overruns,
            s.host_rx_line_errors,
            s.gnss_rx_lost,
            s.gnss_rx_overruns,
            s.gnss_rx_line_errors,
            s.gnss_forwarded,
            s.gnss_not_forwarded,
            s.gnss_bad_checksum,
            s.gnss_overlong,
            s.reset_cause.name(),
            s.settings_source,
            if s.settings_dirty { " (unsaved changes)" } else { "" }
        )),
        Message::DeviceInfo(d) => Some(format!(
            "# device: firmware {}, protocol {}, started by {}, settings {:?} checksum {:08x}",
            escape_control(&d.firmware_version),
            d.protocol_version,
            d.reset_cause.name(),
            d.settings_source,
            d.settings_checksum
        )),
        Message::Reply(r) => Some(format!("# reply: {}", escape_control(r.text.trim_end()))),
        Message::Pose(_) | Message::Gnss(_) => None,
    }
}

/// Text from the unit made safe for a terminal: control characters (escape sequences, CR,
/// backspace, line breaks) shown escaped (`\u{1b}`, `\r`, `\n`), everything else as it is.
pub fn escape_control(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// How `record` and `decode` fill the `t` column: GNSS time when the first record carries
/// it, else MCU time. The rate that turns a GNSS sample index into seconds follows the
/// stream: the rate in use is in every Status, and the Status of a rate switch comes just
/// before the first record at the new rate (docs/PROTOCOL.md, *Rate switch*), so a file
/// may change rate anywhere.
#[derive(Debug, Clone, Copy)]
struct TimeBase {
    /// The records carry GNSS time.
    gnss: bool,
    /// Sample rate in use (Hz), from the latest Status (or `get rate` before the first).
    rate: Option<f64>,
    /// GPS week of the segment's first record with GNSS time: `t` is the time of week of
    /// that week, continuing past 604,800 s across a week rollover.
    week0: Option<u16>,
}

impl TimeBase {
    fn t(&mut self, r: &PoseRecord) -> f64 {
        match self.rate {
            Some(rate) if self.gnss && r.flags.time_valid => {
                let week0 = *self.week0.get_or_insert(r.gnss.week);
                let weeks = f64::from(i32::from(r.gnss.week) - i32::from(week0));
                weeks * f64::from(odo_unit::timing::nmea::SECONDS_PER_WEEK)
                    + f64::from(r.gnss.tow_ms) * 1e-3
                    + f64::from(r.gnss.sample_in_second) / rate
            }
            _ => r.mcu_time_us as f64 * 1e-6,
        }
    }

    /// A Status message: its rate applies to the records that follow it.
    fn on_status(&mut self, s: &Status) {
        if s.rate_hz > 0 {
            self.rate = Some(f64::from(s.rate_hz));
        }
    }
}

/// Why a record does not continue the current segment.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Continuity {
    /// Its time follows the previous record's.
    Next,
    /// The previous record again (same sequence and time): left out, counted.
    Duplicate,
    /// Its time or sample sequence goes back (the unit restarted, or its clock changed): a
    /// new segment.
    Restart,
}

/// Writes pose records as SAMPLES CSV rows of one segment (times increasing).
struct RecordWriter<W: Write> {
    w: W,
    time: TimeBase,
    last: Option<(f64, u32)>,
    last_row: Option<Sample>,
    rows: u64,
    buf: String,
}

impl<W: Write> RecordWriter<W> {
    fn new(mut w: W, time: TimeBase) -> Result<Self> {
        writeln!(w, "{}", SamplesLayout::Record.header())?;
        Ok(Self {
            w,
            time,
            last: None,
            last_row: None,
            rows: 0,
            buf: String::new(),
        })
    }

    /// Whether `r` continues this segment (its time computed as [`Self::row`] would).
    fn continuity(&self, r: &PoseRecord) -> Continuity {
        let t = self.time.clone_t(r);
        match self.last {
            Some((lt, seq)) if t == lt && r.sequence == seq => Continuity::Duplicate,
            // The time went back, or the sample sequence did (a restart of a unit on GNSS
            // time, whose time goes on but whose counts start again).
            Some((lt, seq)) if t <= lt || r.sequence.wrapping_sub(seq) > u32::MAX / 2 => {
                Continuity::Restart
            }
            _ => Continuity::Next,
        }
    }

    fn row(&mut self, r: &PoseRecord) -> Result<()> {
        let t = self.time.t(r);
        self.last = Some((t, r.sequence));
        let sample = Sample {
            t,
            left: r.gamma_left,
            right: r.gamma_right,
            left_index: r.flags.left.index_seen.then_some(r.index_left),
            right_index: r.flags.right.index_seen.then_some(r.index_right),
            flags: Some(u64::from(r.flags.to_bits())),
            unit: Some(UnitPose {
                seq: Some(u64::from(r.sequence)),
                x: r.x,
                y: r.y,
                heading: r.heading,
                sigma_x: r.sigma_x,
                sigma_y: r.sigma_y,
                sigma_heading: r.sigma_heading,
                cov_xy: r.cov_xy,
                time: None,
            }),
        };
        let clocks: RecordFields = [
            r.mcu_time_us,
            u64::from(r.gnss.week),
            u64::from(r.gnss.tow_ms),
            u64::from(r.gnss.sample_in_second),
            u64::from(r.dropped),
        ];
        self.buf.clear();
        SamplesLayout::Record.push_row(&mut self.buf, &sample, Some(&clocks));
        self.last_row = Some(SamplesLayout::Record.read_back(&sample, Some(&clocks)));
        self.w.write_all(self.buf.as_bytes())?;
        self.rows += 1;
        Ok(())
    }
}

impl TimeBase {
    /// [`TimeBase::t`] without fixing the week.
    fn clone_t(&self, r: &PoseRecord) -> f64 {
        let mut copy = *self;
        copy.t(r)
    }
}

/// Where the segments of a recording go: the first to `first`, segment `k` >= 2 to the
/// file named like `first` with `-k` before its extension (`rec.csv`, `rec-2.csv`, ...);
/// with `first = None` (stdout) later segments cannot be written and are counted.
pub fn segment_path(first: &Path, k: usize) -> PathBuf {
    if k <= 1 {
        return first.to_path_buf();
    }
    let stem = first
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let name = match first.extension() {
        Some(ext) => format!("{stem}-{k}.{}", ext.to_string_lossy()),
        None => format!("{stem}-{k}"),
    };
    first.with_file_name(name)
}

/// The records of a capture as SAMPLES CSV segments: a new segment (file) wherever the
/// time does not increase, duplicates left out and counted.
pub struct SegmentWriter<'a> {
    /// The first segment's file (`None`: `stdout`).
    first: Option<&'a Path>,
    stdout: Option<Box<dyn Write + 'a>>,
    /// Sample rate in use (Hz), from the latest Status.
    rate: Option<f64>,
    current: Option<RecordWriter<Box<dyn Write + 'a>>>,
    /// (file, rows) of each finished segment.
    done: Vec<(String, u64)>,
    /// Exact repeats of the previous record, left out.
    duplicates: u64,
    /// Records of later segments that had nowhere to go (stdout), left out.
    unwritten: u64,
    segments: usize,
}

impl<'a> SegmentWriter<'a> {
    /// A writer of the first segment to `first`, or to `stdout` when `first` is `None`; `rate`
    /// is the sample rate (Hz) until a Status gives one.
    pub fn new(
        first: Option<&'a Path>,
        stdout: Option<Box<dyn Write + 'a>>,
        rate: Option<f64>,
    ) -> Self {
        Self {
            first,
            stdout,
            rate,
            current: None,
            done: Vec::new(),
            duplicates: 0,
            unwritten: 0,
            segments: 0,
        }
    }

    fn open(&mut self, r: &PoseRecord) -> Result<()> {
        self.finish_segment()?;
        self.segments += 1;
        let w: Box<dyn Write + 'a> = match (self.first, self.stdout.take()) {
            (Some(first), _) => {
                let p = segment_path(first, self.segments);
                Box::new(BufWriter::new(
                    File::create(&p).with_context(|| format!("{}: cannot create", p.display()))?,
                ))
            }
            (None, Some(out)) => out,
            (None, None) => {
                self.unwritten += 1;
                return Ok(());
            }
        };
        let time = TimeBase {
            gnss: r.flags.time_valid,
            rate: self.rate,
            week0: None,
        };
        self.current = Some(RecordWriter::new(w, time)?);
        Ok(())
    }

    /// A Status message: its rate applies to the records that follow it, in this segment
    /// and the next.
    pub fn on_status(&mut self, s: &Status) {
        if s.rate_hz > 0 {
            self.rate = Some(f64::from(s.rate_hz));
        }
        if let Some(w) = &mut self.current {
            w.time.on_status(s);
        }
    }

    /// Writes `r`: to the current segment, or a new one after a restart.
    pub fn push(&mut self, r: &PoseRecord) -> Result<()> {
        let continuity = match &self.current {
            Some(w) => w.continuity(r),
            None if self.segments > 0 => {
                // Stdout is taken by the first segment: count what follows.
                self.unwritten += 1;
                return Ok(());
            }
            None => Continuity::Restart,
        };
        match continuity {
            Continuity::Duplicate => {
                self.duplicates += 1;
                return Ok(());
            }
            Continuity::Restart => {
                self.open(r)?;
                if self.current.is_none() {
                    return Ok(());
                }
            }
            Continuity::Next => {}
        }
        self.current.as_mut().expect("open segment").row(r)
    }

    /// The SAMPLES row of the last record written to the current segment, as the reader
    /// gives it back from the file.
    pub fn last_row(&self) -> Option<Sample> {
        self.current.as_ref()?.last_row
    }

    /// The current segment (1 for the first file, 0 before any) and the rows written to it.
    pub fn position(&self) -> (usize, u64) {
        (self.segments, self.current.as_ref().map_or(0, |w| w.rows))
    }

    fn finish_segment(&mut self) -> Result<()> {
        if let Some(mut w) = self.current.take() {
            w.w.flush()?;
            let name = match self.first {
                Some(first) => segment_path(first, self.segments).display().to_string(),
                None => "stdout".into(),
            };
            self.done.push((name, w.rows));
        }
        Ok(())
    }

    /// Flushes; the report: (file, rows) per segment, duplicates, unwritten records.
    pub fn finish(mut self) -> Result<Recorded> {
        self.finish_segment()?;
        if self.segments == 0 {
            // No record: an empty CSV (header only) where the first segment goes.
            let mut w: Box<dyn Write + 'a> = match (self.first, self.stdout.take()) {
                (Some(p), _) => Box::new(
                    File::create(p).with_context(|| format!("{}: cannot create", p.display()))?,
                ),
                (None, Some(out)) => out,
                (None, None) => unreachable!("stdout is taken by a segment only"),
            };
            writeln!(w, "{}", SamplesLayout::Record.header())?;
            w.flush()?;
        }
        Ok(Recorded {
            segments: self.done,
            duplicates: self.duplicates,
            unwritten: self.unwritten,
        })
    }
}

/// What `record` or `decode` wrote and left out.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recorded {
    /// (file, rows) of each segment, in order.
    pub segments: Vec<(String, u64)>,
    /// Exact repeats of the previous record (same sequence and time), left out.
    pub duplicates: u64,
    /// Records of segments after the first that could not be written (output to stdout).
    pub unwritten: u64,
}

impl Recorded {
    /// Rows written over all segments.
    pub fn rows(&self) -> u64 {
        self.segments.iter().map(|(_, n)| n).sum()
    }

    /// One line per segment and one per kind of record left out (each with its count).
    pub fn report(&self) -> String {
        let mut out = String::new();
        let n = self.segments.len();
        for (i, (file, rows)) in self.segments.iter().enumerate() {
            if n > 1 {
                out.push_str(&format!(
                    "segment {} of {n}: {rows} records to {file}{}\n",
                    i + 1,
                    if i > 0 {
                        " (the unit restarted or its time went back: a new segment)"
                    } else {
                        ""
                    }
                ));
            } else {
                out.push_str(&format!("{rows} records to {file}\n"));
            }
        }
        if self.duplicates > 0 {
            out.push_str(&format!(
                "left out: {} duplicate records (same sequence and time as the one before)\n",
                self.duplicates
            ));
        }
        if self.unwritten > 0 {
            out.push_str(&format!(
                "left out: {} records after a restart (a new segment cannot go to stdout: use --out)\n",
                self.unwritten
            ));
        }
        out
    }
}

/// Decodes a raw capture into the `record` CSV: the first segment to `out` (or `stdout`
/// when `out` is `None`), each later segment (after a restart) to its own file
/// ([`segment_path`]); returns what was written and left out, and the decoder and stream
/// counters.
pub fn decode_bytes<'a>(
    bytes: &[u8],
    out: Option<&'a Path>,
    stdout: Option<Box<dyn Write + 'a>>,
) -> Result<(Recorded, DecoderStats, StreamStats)> {
    let mut decoder = FrameDecoder::new();
    let mut frames = Vec::new();
    decoder.feed(bytes, |f| {
        if let Ok(f) = f {
            frames.push(f);
        }
    });
    let mut stats = StreamStats::default();
    // Records before the first Status (a capture started mid-second) take its rate.
    let rate = frames.iter().find_map(|f| match &f.message {
        Message::Status(s) if s.rate_hz > 0 => Some(f64::from(s.rate_hz)),
        _ => None,
    });
    let mut w = SegmentWriter::new(out, stdout, rate);
    for f in &frames {
        match &f.message {
            Message::Pose(r) => {
                stats.on_record(r);
                w.push(r)?;
            }
            Message::Status(st) => w.on_status(st),
            _ => {}
        }
    }
    Ok((w.finish()?, decoder.stats(), stats))
}
