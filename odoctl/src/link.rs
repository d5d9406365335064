//! The link to the unit: a serial port (`serialport`, no libudev) or a TCP socket
//! (`tcp:HOST:PORT`, the QEMU image's USART2), framed by the core's protocol code
//! (`odo_core::protocol`: COBS frames with CRC-32, `FrameDecoder` with loss accounting).
//!
//! Subcommands `monitor`, `record`, `decode` and `config`.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufWriter, ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use odo_core::protocol::{DecoderStats, Frame, FrameDecoder, Message, PoseRecord};
use odo_core::timing::SyncState;

use crate::config as cfg;
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
        "frames {}, CRC errors {}, malformed {}, oversize {}, version errors {}, unknown types {}, frame sequence gaps {} ({} frames lost); records {}, record sequence gaps {}, dropped by the unit {}",
        d.frames,
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
            Err(e) => return Err(e).context("reading from the unit"),
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

    /// Sends one command line.
    pub fn send_line(&mut self, line: &str) -> Result<()> {
        self.link.write_all(line.as_bytes())?;
        self.link.write_all(b"\n")?;
        self.link.flush()?;
        Ok(())
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

const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

fn sync_name(m: SyncState) -> &'static str {
    match m {
        SyncState::FreeRunning => "free",
        SyncState::Locked => "pps",
        SyncState::Holdover => "hold",
    }
}

/// One line of the human table of `monitor`.
pub fn table_row(r: &PoseRecord) -> String {
    let wheel = |w: &odo_core::protocol::WheelStatus| {
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

fn describe(f: &Frame) -> Option<String> {
    match &f.message {
        Message::Status(s) => Some(format!(
            "# status: uptime {:.1} s, rate {} Hz, sync {}, samples {}, dropped {}, samples lost {}, merged {}, PPS edges {} (rejected {}), rx errors {}, GNSS rx lost {}, settings {:?}{}",
            s.uptime_us as f64 * 1e-6,
            s.rate_hz,
            sync_name(s.flags.sync),
            s.samples,
            s.dropped_total,
            s.samples_lost,
            s.merged_samples,
            s.pps_edges,
            s.pps_rejected,
            s.rx_errors,
            s.gnss_rx_lost,
            s.settings_source,
            if s.settings_dirty { " (unsaved changes)" } else { "" }
        )),
        Message::DeviceInfo(d) => Some(format!(
            "# device: firmware {}, protocol {}, settings {:?} checksum {:08x}",
            d.firmware_version, d.protocol_version, d.settings_source, d.settings_checksum
        )),
        Message::Reply(r) => Some(format!("# reply: {}", r.text.trim_end())),
        Message::Pose(_) => None,
    }
}

/// `odoctl monitor`.
pub fn monitor(
    port: &str,
    baud: u32,
    duration: Option<f64>,
    count: Option<u64>,
    every: u64,
) -> Result<ExitCode> {
    let mut s = Session::new(open(port, baud)?, None)?;
    let end = duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let mut out = std::io::stdout().lock();
    writeln!(out, "{TABLE_HEADER}")?;
    let mut last_report = Instant::now();
    let mut n = 0u64;
    while let Some(f) = s.next_frame(end)? {
        match &f.message {
            Message::Pose(r) => {
                if n % every.max(1) == 0 {
                    writeln!(out, "{}", table_row(r))?;
                }
                n += 1;
                if count.is_some_and(|c| n >= c) {
                    break;
                }
            }
            _ => {
                if let Some(d) = describe(&f) {
                    writeln!(out, "{d}")?;
                }
            }
        }
        if last_report.elapsed() >= Duration::from_secs(5) {
            writeln!(out, "# link: {}", health(&s.decoder_stats(), &s.stats))?;
            last_report = Instant::now();
        }
        out.flush()?;
    }
    writeln!(out, "# link: {}", health(&s.decoder_stats(), &s.stats))?;
    if s.closed() {
        writeln!(out, "# the unit closed the connection")?;
    }
    Ok(ExitCode::SUCCESS)
}

/// How `record` and `decode` fill the `t` column.
#[derive(Debug, Clone, Copy)]
struct TimeBase {
    /// Sample rate for GNSS time (Hz), when the records carry valid GNSS time.
    gnss_rate: Option<f64>,
}

impl TimeBase {
    fn t(&self, r: &PoseRecord) -> f64 {
        match self.gnss_rate {
            Some(rate) if r.flags.time_valid => {
                f64::from(r.gnss.tow_ms) * 1e-3 + f64::from(r.gnss.sample_in_second) / rate
            }
            _ => r.mcu_time_us as f64 * 1e-6,
        }
    }
}

/// Writes pose records as SAMPLES CSV rows; skips rows whose time does not increase.
struct RecordWriter<W: Write> {
    w: W,
    time: TimeBase,
    last_t: Option<f64>,
    rows: u64,
    skipped: u64,
    buf: String,
}

impl<W: Write> RecordWriter<W> {
    fn new(mut w: W, time: TimeBase) -> Result<Self> {
        writeln!(w, "{}", SamplesLayout::Record.header())?;
        Ok(Self {
            w,
            time,
            last_t: None,
            rows: 0,
            skipped: 0,
            buf: String::new(),
        })
    }

    fn row(&mut self, r: &PoseRecord) -> Result<()> {
        let t = self.time.t(r);
        if self.last_t.is_some_and(|l| t <= l) {
            self.skipped += 1;
            return Ok(());
        }
        self.last_t = Some(t);
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
                sigma_xy: r.sigma_xy,
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
        self.w.write_all(self.buf.as_bytes())?;
        self.rows += 1;
        Ok(())
    }
}

fn parse_rate(text: &str) -> Option<f64> {
    text.lines().find_map(|l| {
        l.trim()
            .strip_prefix("rate")
            .and_then(|r| r.trim().strip_prefix('='))
            .and_then(|v| v.trim().parse().ok())
    })
}

/// `odoctl record`.
pub fn record(
    port: &str,
    baud: u32,
    out: &Path,
    raw: Option<&Path>,
    duration: Option<f64>,
    count: Option<u64>,
    reset_pose: bool,
) -> Result<ExitCode> {
    let mut s = Session::new(open(port, baud)?, raw)?;
    // The sample rate turns the GNSS time tag (second + sample index) into seconds.
    let (ok, text) = s.command("get rate", REPLY_TIMEOUT)?;
    let rate = if ok { parse_rate(&text) } else { None };
    let mut early = Vec::new();
    let mut started = !reset_pose;
    if reset_pose {
        // The unit answers and applies the reset at its next sample, whose record carries
        // the reset pose with zero sigmas: the recording starts there.
        let (ok, text) = s.command_with("reset_pose", REPLY_TIMEOUT, |f| {
            if let Message::Pose(r) = &f.message {
                early.push(*r);
            }
        })?;
        if !ok {
            bail!("reset_pose: {}", text.trim());
        }
    }
    let is_start = |r: &PoseRecord| {
        r.x == 0.0
            && r.y == 0.0
            && r.heading == 0.0
            && r.sigma_x == 0.0
            && r.sigma_y == 0.0
            && r.sigma_heading == 0.0
    };
    let file = File::create(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut writer: Option<RecordWriter<BufWriter<File>>> = None;
    let mut file = Some(BufWriter::new(file));
    let end = duration.map(|d| Instant::now() + Duration::from_secs_f64(d));
    let start_deadline = Instant::now() + REPLY_TIMEOUT;
    let mut queue: VecDeque<PoseRecord> = early.into();
    loop {
        let r = match queue.pop_front() {
            Some(r) => r,
            None => match s.next_frame(end)? {
                Some(Frame {
                    message: Message::Pose(r),
                    ..
                }) => r,
                Some(f) => {
                    if let Some(d) = describe(&f) {
                        eprintln!("{d}");
                    }
                    continue;
                }
                None => break,
            },
        };
        if !started {
            if is_start(&r) {
                started = true;
            } else if Instant::now() > start_deadline {
                bail!(
                    "reset_pose: no record with the reset pose and zero sigmas within {} s",
                    REPLY_TIMEOUT.as_secs()
                );
            } else {
                continue;
            }
        }
        let w = match &mut writer {
            Some(w) => w,
            None => {
                let time = TimeBase {
                    gnss_rate: if r.flags.time_valid { rate } else { None },
                };
                writer.insert(RecordWriter::new(file.take().expect("file once"), time)?)
            }
        };
        w.row(&r)?;
        if count.is_some_and(|c| w.rows >= c) {
            break;
        }
    }
    s.finish()?;
    let (rows, skipped) = match &mut writer {
        Some(w) => {
            w.w.flush()?;
            (w.rows, w.skipped)
        }
        None => {
            if let Some(mut f) = file.take() {
                writeln!(f, "{}", SamplesLayout::Record.header())?;
                f.flush()?;
            }
            (0, 0)
        }
    };
    eprintln!(
        "recorded {rows} records to {}{}",
        out.display(),
        if skipped > 0 {
            format!(" ({skipped} skipped: time not increasing)")
        } else {
            String::new()
        }
    );
    eprintln!("link: {}", health(&s.decoder_stats(), &s.stats));
    if s.stats.record_gaps > 0 || s.stats.dropped_by_unit > 0 {
        eprintln!("warning: records are missing; a replay integrates across the gaps and will differ from the unit there");
    }
    if rows == 0 {
        bail!("no pose record received");
    }
    Ok(ExitCode::SUCCESS)
}

/// Decodes a raw capture into the `record` CSV; returns (rows, decoder stats, stream stats).
pub fn decode_bytes(bytes: &[u8], out: &mut dyn Write) -> Result<(u64, DecoderStats, StreamStats)> {
    let mut decoder = FrameDecoder::new();
    let mut frames = Vec::new();
    decoder.feed(bytes, |f| {
        if let Ok(f) = f {
            frames.push(f);
        }
    });
    let mut stats = StreamStats::default();
    let first_valid = frames.iter().find_map(|f| match &f.message {
        Message::Pose(r) => Some(r.flags.time_valid),
        _ => None,
    });
    let rate = frames.iter().find_map(|f| match &f.message {
        Message::Status(s) if s.rate_hz > 0 => Some(f64::from(s.rate_hz)),
        _ => None,
    });
    let time = TimeBase {
        gnss_rate: if first_valid == Some(true) {
            rate
        } else {
            None
        },
    };
    let mut w = RecordWriter::new(out, time)?;
    for f in &frames {
        if let Message::Pose(r) = &f.message {
            stats.on_record(r);
            w.row(r)?;
        }
    }
    Ok((w.rows, decoder.stats(), stats))
}

/// `odoctl decode`.
pub fn decode(file: &Path, out: Option<&Path>) -> Result<ExitCode> {
    let bytes = std::fs::read(file).with_context(|| format!("{}: cannot read", file.display()))?;
    let (rows, d, s) = match out {
        Some(p) => {
            let mut w = BufWriter::new(
                File::create(p).with_context(|| format!("{}: cannot create", p.display()))?,
            );
            let r = decode_bytes(&bytes, &mut w)?;
            w.flush()?;
            r
        }
        None => {
            let mut w = BufWriter::new(std::io::stdout().lock());
            let r = decode_bytes(&bytes, &mut w)?;
            w.flush()?;
            r
        }
    };
    eprintln!(
        "{}: {rows} pose records; {}",
        file.display(),
        health(&d, &s)
    );
    if rows == 0 {
        bail!(
            "{}: no pose record in {} bytes",
            file.display(),
            bytes.len()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// What `config` does.
#[derive(Debug, Clone)]
pub enum ConfigAction {
    /// `get [KEY]`.
    Get(Option<String>),
    /// `set KEY VALUE`.
    Set(String, String),
    /// `save`.
    Save,
    /// Send a parameter file; then `save` when true.
    Push(PathBuf, bool),
    /// `get`, written to a TOML file.
    Pull(PathBuf),
    /// Any command line.
    Raw(String),
}

/// `odoctl config`: prints the unit's replies; exit code 1 on an error reply.
pub fn config(port: &str, baud: u32, action: ConfigAction) -> Result<ExitCode> {
    let lines: Vec<String> = match &action {
        ConfigAction::Get(None) => vec!["get".into()],
        ConfigAction::Get(Some(k)) => vec![format!("get {k}")],
        ConfigAction::Set(k, v) => vec![format!("set {k} {v}")],
        ConfigAction::Save => vec!["save".into()],
        ConfigAction::Push(p, save) => {
            let mut l = cfg::push_lines(p)?;
            if *save {
                l.push("save".into());
            }
            l
        }
        ConfigAction::Pull(_) => vec!["get".into()],
        ConfigAction::Raw(l) => vec![l.clone()],
    };
    if lines.iter().any(|l| l.contains('\n') || l.contains('\r')) {
        bail!("a command must be one line");
    }
    let mut s = Session::new(open(port, baud)?, None)?;
    for line in &lines {
        let (ok, text) = s.command(line, REPLY_TIMEOUT)?;
        crate::outln!("> {line}");
        for l in text.lines() {
            crate::outln!("{l}");
        }
        if !ok {
            eprintln!("odoctl: the unit rejected `{line}`");
            return Ok(ExitCode::FAILURE);
        }
        if let ConfigAction::Pull(path) = &action {
            let (settings, keys) = cfg::parse_get_reply(&text)?;
            let toml =
                cfg::render_settings(&settings, &keys, "odoctl config pull: the unit's settings");
            std::fs::write(path, toml)
                .with_context(|| format!("{}: cannot write", path.display()))?;
            crate::outln!("wrote {}", path.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}
