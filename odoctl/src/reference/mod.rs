//! The RTK reference of a calibration from any of the files a user has: the REFERENCE CSV in
//! local metres ([`crate::csvio`]), the receiver's NMEA 0183 log ([`nmea`]), a u-blox UBX log
//! ([`ubx`], recognised by [`ubx::sniff`] before the text formats) or an RTKLIB `.pos`
//! solution ([`rtklib`]), recognised from the content ([`detect`]).
//!
//! A receiver log gives WGS84 positions at GPS times ([`Epoch`]); [`Reference::from_log`]
//! keeps the epochs of the required fix quality ([`MinFix`]: RTK-fixed by default), turns their
//! positions into local east-north-up metres around an origin ([`geodetic`], [`OriginChoice`])
//! and reports what it used and why it left the rest out ([`UseReport`]). [`Reference::ref_points`]
//! hands the result over as the rows the calibration matches with the samples, on the samples'
//! time base (GPS time of week, as `record` writes it), refusing a log that does not overlap
//! the samples.

pub mod clock;
pub mod geodetic;
pub mod gps_time;
pub mod matched;
pub mod mcap_pose;
pub mod nmea;
pub mod rtklib;
pub mod simulated;
pub mod simulated_trajectory;
pub mod stream;
pub mod summary;
pub mod trajectory;
pub mod trajectory_noise;
pub mod tum;
pub mod ubx;

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use crate::cancel::check_this_thread;
use crate::csvio::{self, RefPoint, Sample};
use geodetic::{Geodetic, LocalFrame};

/// The kind of a reference file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// REFERENCE CSV: `t,x,y[,heading]` in local metres on the samples' time base.
    Csv,
    /// NMEA 0183 log: GGA (+ RMC or ZDA for the date, HDT, GST).
    Nmea,
    /// RTKLIB `.pos` solution (latitude/longitude/height).
    Rtklib,
    /// TUM trajectory (`timestamp tx ty tz qx qy qz qw`) of a marker in a local frame.
    Tum,
    /// ROS 2 MCAP recording with a PoseStamped, Odometry or TFMessage topic.
    Mcap,
    /// u-blox UBX log: NAV-PVT (+ NAV-HPPOSLLH, NAV-RELPOSNED), in any mix with NMEA and RTCM 3.
    Ubx,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Csv => "REFERENCE CSV",
            Self::Nmea => "NMEA 0183",
            Self::Rtklib => "RTKLIB .pos",
            Self::Tum => "TUM trajectory",
            Self::Mcap => "MCAP",
            Self::Ubx => "u-blox UBX",
        })
    }
}

/// Recognises the format from the first 50 non-blank lines: a `$` sentence with a `*hh`
/// checksum is NMEA (binary data before it, as in a receiver's mixed log, is passed over,
/// even when it starts with `%`); a `%` header of text or a data row starting `yyyy/mm/dd`
/// or `week tow` with at least 14 columns is RTKLIB; a line of exactly 8 numbers separated by
/// white space is TUM (`#` lines passed over); anything else is taken as CSV (whose own parser
/// then names what is wrong). MCAP is recognised by its magic bytes ([`detect_format`]).
pub fn detect(text: &str) -> Format {
    let mut d = TextFormat::default();
    for (_, line) in crate::text::lines(text) {
        if d.line(line) {
            break;
        }
    }
    d.format()
}

/// Lines [`detect`] looks at (trimmed, neither empty nor a comment) for a format.
const DETECT_LINES: usize = 50;

/// [`detect`] line by line: the format of the first of [`DETECT_LINES`] lines (trimmed,
/// neither empty nor a comment) that tells one, else CSV.
#[derive(Debug, Clone, Default)]
pub struct TextFormat {
    looked: usize,
    found: Option<Format>,
}

impl TextFormat {
    /// Looks at the next line (without its line end); true once the format is decided.
    pub fn line(&mut self, raw: &str) -> bool {
        if self.found.is_some() || self.looked >= DETECT_LINES {
            return true;
        }
        let line = raw.trim();
        if !line.is_empty() && !line.starts_with('#') {
            self.looked += 1;
            self.found = line_format(line);
        }
        self.found.is_some() || self.looked >= DETECT_LINES
    }

    /// The format of the lines looked at.
    pub fn format(&self) -> Format {
        self.found.unwrap_or(Format::Csv)
    }
}

/// The format a line (trimmed, neither empty nor a comment) tells, if any.
fn line_format(line: &str) -> Option<Format> {
    if tum::is_pose_line(line) {
        return Some(Format::Tum);
    }
    if is_rtklib_header(line) {
        return Some(Format::Rtklib);
    }
    if let Some(i) = line.find('$') {
        let s = &line[i + 1..];
        let address = s.split(',').next().unwrap_or("");
        if address.len() >= 3
            && address.bytes().all(|b| b.is_ascii_alphanumeric())
            && s.contains('*')
        {
            return Some(Format::Nmea);
        }
    }
    let tokens: Vec<&str> = line.split_whitespace().collect();
    if tokens.len() >= 14 {
        let first = tokens[0];
        let calendar = first.len() == 10 && first.as_bytes()[4] == b'/';
        let week = first.parse::<u32>().is_ok() && tokens[1].parse::<f64>().is_ok();
        if calendar || week {
            return Some(Format::Rtklib);
        }
    }
    None
}

/// Recognises the format of a file's bytes (`text`: the same as text): MCAP by its magic,
/// a UBX log ([`ubx::sniff`]), then [`detect`].
pub fn detect_format(bytes: &[u8], text: &str) -> Format {
    if bytes.starts_with(mcap_pose::MAGIC) {
        Format::Mcap
    } else if ubx::sniff(bytes) {
        Format::Ubx
    } else {
        detect(text)
    }
}

/// An RTKLIB header line: `%`, then nothing or a space and printable ASCII (`% program :
/// RTKPOST`), not binary data that happens to start with `%`.
fn is_rtklib_header(line: &str) -> bool {
    line.strip_prefix('%').is_some_and(|rest| {
        (rest.is_empty() || rest.starts_with([' ', '\t']))
            && rest
                .bytes()
                .all(|b| b == b'\t' || (b' '..=b'~').contains(&b))
    })
}

/// Solution quality of an epoch, as GGA's quality field and RTKLIB's Q column give it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FixQuality {
    /// RTK with fixed integer ambiguities (GGA 4, Q = 1).
    RtkFixed,
    /// RTK with float ambiguities (GGA 5, Q = 2).
    RtkFloat,
    /// Precise point positioning (Q = 6).
    Ppp,
    /// Differential code (GGA 2, Q = 4).
    Dgps,
    /// SBAS-corrected (Q = 3).
    Sbas,
    /// Autonomous single point (GGA 1 and 3, Q = 5).
    Single,
    /// No fix, or estimated, manual or simulated (GGA 0, 6, 7, 8; other Q values).
    Invalid,
}

impl fmt::Display for FixQuality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::RtkFixed => "RTK fixed",
            Self::RtkFloat => "RTK float",
            Self::Ppp => "PPP",
            Self::Dgps => "DGPS",
            Self::Sbas => "SBAS",
            Self::Single => "single",
            Self::Invalid => "no valid fix",
        })
    }
}

/// The least fix quality an epoch needs to be used (`--min-fix`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum MinFix {
    /// RTK fixed only (the default).
    #[default]
    Fixed,
    /// RTK fixed or float.
    Float,
    /// Any valid position (also PPP, DGPS, SBAS, single).
    Any,
}

impl MinFix {
    /// True when an epoch of quality `q` is used.
    pub fn accepts(self, q: FixQuality) -> bool {
        match self {
            Self::Fixed => q == FixQuality::RtkFixed,
            Self::Float => matches!(q, FixQuality::RtkFixed | FixQuality::RtkFloat),
            Self::Any => q != FixQuality::Invalid,
        }
    }
}

/// One position of a receiver log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Epoch {
    /// GPS time (s since 1980-01-06 00:00:00 GPS).
    pub gps_time: f64,
    /// WGS84 position of the antenna.
    pub position: Geodetic,
    /// True heading (rad, clockwise from north), when the log has one (NMEA HDT).
    pub heading: Option<f64>,
    /// Standard deviations north, east, up (m), when the log has them (GST; `.pos` sdn/sde/sdu).
    pub sigma_north_east_up: Option<[f64; 3]>,
    /// Solution quality.
    pub fix: FixQuality,
    /// 1-based line of the position in the file (a UBX log: the byte offset of its NAV-PVT).
    pub line: usize,
}

/// How many of each kind of line or record a parser met, and the first problems, each as
/// `FILE:LINE: ...`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadReport {
    /// Sentences or records used, by kind (`GGA`, `RMC`, `ZDA`, `HDT`, `GST`, `pos`).
    pub used: BTreeMap<String, usize>,
    /// Well-formed sentences of kinds that carry nothing used here, by kind (`GSV`...).
    pub other: BTreeMap<String, usize>,
    /// Corrupt lines or frames (checksum, syntax, field out of range, cut off): skipped.
    pub corrupt: usize,
    /// Well-formed lines without what they should carry (a GGA without a position, an RMC
    /// with status V, an epoch whose time is not after the previous one...): skipped.
    pub unusable: usize,
    /// Lines with stray bytes before, between or after their sentences (binary messages
    /// between the sentences): the sentences are read, the bytes skipped.
    pub stray_bytes: usize,
    /// Bytes skipped outside any sentence or frame (stray bytes on a line, binary data
    /// between the frames of a binary log).
    pub skipped_bytes: usize,
    /// Lines that hold more than one sentence (a lost line feed): each sentence is read.
    pub joined: usize,
    /// NMEA talkers seen (`GN`, `GP`...; `P` + maker for proprietary sentences), by count.
    pub talkers: BTreeMap<String, usize>,
    /// The receiver as the log names it (u-blox MON-VER), when it does.
    pub receiver: Option<String>,
    /// How the reader read the log (the HDT order it detected, the heading source...).
    pub notes: Vec<String>,
    /// The first problems (at most [`ReadReport::KEPT`]), `FILE:LINE: ...`.
    pub problems: Vec<String>,
    /// Warnings about what was read (a date past the leap-second table), `FILE:LINE: ...`.
    pub warnings: Vec<String>,
}

impl ReadReport {
    /// How many problem messages are kept.
    pub const KEPT: usize = 5;

    /// Counts a corrupt line.
    pub fn corrupt(&mut self, msg: String) {
        self.corrupt += 1;
        self.problem(msg);
    }

    /// Counts an unusable line.
    pub fn unusable(&mut self, msg: String) {
        self.unusable += 1;
        self.problem(msg);
    }

    /// Counts a line read after stray bytes.
    pub fn stray_bytes(&mut self, msg: String) {
        self.stray_bytes += 1;
        self.problem(msg);
    }

    fn problem(&mut self, msg: String) {
        if self.problems.len() < Self::KEPT {
            self.problems.push(msg);
        }
    }

    /// Counts a used sentence or record of `kind`.
    pub fn used(&mut self, kind: &str) {
        *self.used.entry(kind.to_string()).or_default() += 1;
    }

    /// Counts another sentence of `kind` (quoted as a short excerpt).
    pub fn other(&mut self, kind: &str) {
        *self.other.entry(crate::text::excerpt(kind)).or_default() += 1;
    }
}

impl fmt::Display for ReadReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let list = |m: &BTreeMap<String, usize>| {
            m.iter()
                .map(|(k, v)| format!("{v} {k}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        write!(f, "read: {}", list(&self.used))?;
        if !self.other.is_empty() {
            write!(f, "; other messages skipped: {}", list(&self.other))?;
        }
        write!(
            f,
            "; {} corrupt and {} unusable lines or frames skipped",
            self.corrupt, self.unusable
        )?;
        if self.stray_bytes > 0 {
            write!(
                f,
                "; {} lines with stray bytes besides their sentences (the sentences read)",
                self.stray_bytes
            )?;
        }
        if self.joined > 0 {
            write!(
                f,
                "; {} lines with more than one sentence (each read)",
                self.joined
            )?;
        }
        if self.skipped_bytes > 0 {
            write!(
                f,
                "; {} bytes outside any sentence or frame skipped",
                self.skipped_bytes
            )?;
        }
        for n in &self.notes {
            write!(f, "\n    {n}")?;
        }
        for p in &self.problems {
            write!(f, "\n    {p}")?;
        }
        Ok(())
    }
}

/// What a parser gives: the epochs in file order (times strictly increasing) and its report.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GeodeticLog {
    /// The epochs.
    pub epochs: Vec<Epoch>,
    /// What was read and skipped.
    pub report: ReadReport,
}

/// Where the local plane's origin is.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum OriginChoice {
    /// A given position (`--origin LAT,LON,H`).
    Given(Geodetic),
    /// The first used epoch.
    FirstEpoch,
    /// The mean of the used epochs over the opening standstill: the leading epochs within
    /// [`STANDSTILL_RADIUS`] of the first (the first epoch alone when the log starts moving).
    #[default]
    OpeningStandstill,
}

/// Horizontal radius (m) within which the leading epochs count as the opening standstill: five
/// times an RTK-fixed epoch's noise (8 mm RMS for the paper's BD982), far below a start's motion.
pub const STANDSTILL_RADIUS: f64 = 0.04;

/// Options of reading a reference file.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceOptions {
    /// The format, or `None` to recognise it from the content.
    pub format: Option<Format>,
    /// The least fix quality used.
    pub min_fix: MinFix,
    /// The local origin.
    pub origin: OriginChoice,
    /// GPS - UTC (s) for NMEA logs (UTC times) and RTKLIB files written in UTC; `None`: by
    /// each epoch's date ([`gps_time::leap_seconds_on`]).
    pub leap_seconds: Option<i32>,
    /// The topic (and TF frames) of an MCAP reference.
    pub mcap: mcap_pose::McapSelect,
    /// For a trajectory reference (TUM, MCAP): samples' `t` = reference stamp + this (s);
    /// `None`: see [`Reference::points_for`].
    pub time_offset: Option<f64>,
    /// For a trajectory reference: the rate of the samples' clock against the stamps, less 1
    /// (ppm); `None`: estimated.
    pub clock_ppm: Option<f64>,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        Self {
            format: None,
            min_fix: MinFix::Fixed,
            origin: OriginChoice::OpeningStandstill,
            leap_seconds: None,
            mcap: mcap_pose::McapSelect::default(),
            time_offset: None,
            clock_ppm: None,
        }
    }
}

/// The time scale of a [`Reference`]'s `t`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeScale {
    /// GPS seconds since 1980-01-06 (receiver logs).
    Gps,
    /// The samples' own time base (a REFERENCE CSV: matched as it is).
    Samples,
    /// The stamps of a trajectory reference (TUM, MCAP) on its own clock, interpolated at the
    /// sample instants ([`Reference::points_for`]).
    Trajectory,
}

/// One used reference epoch in the local plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalEpoch {
    /// Time (s) on the reference's [`TimeScale`].
    pub t: f64,
    /// East (m).
    pub x: f64,
    /// North (m).
    pub y: f64,
    /// Up (m), for receiver logs.
    pub up: Option<f64>,
    /// Heading (rad, clockwise from +y (north)), when the reference has one.
    pub heading: Option<f64>,
    /// Standard deviations east, north (m), when the reference has them.
    pub sigma_east_north: Option<[f64; 2]>,
    /// Solution quality (CSV rows: taken as RTK fixed).
    pub fix: FixQuality,
    /// 1-based line in the file.
    pub line: usize,
}

/// Which epochs were used and why the others were left out.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UseReport {
    /// Epochs read (with a position).
    pub epochs: usize,
    /// Epochs used.
    pub used: usize,
    /// Epochs left out for their fix quality, by quality.
    pub below_min_fix: BTreeMap<FixQuality, usize>,
    /// The parser's report (empty for a CSV).
    pub read: ReadReport,
    /// What else was found or done, one line each (a trajectory's topic, its marker's yaw).
    pub notes: Vec<String>,
}

impl fmt::Display for UseReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} epochs read, {} used", self.epochs, self.used)?;
        if !self.below_min_fix.is_empty() {
            let left: Vec<String> = self
                .below_min_fix
                .iter()
                .map(|(q, n)| format!("{n} {q}"))
                .collect();
            write!(
                f,
                "; left out for their fix quality (--min-fix): {}",
                left.join(", ")
            )?;
        }
        if self.read != ReadReport::default() {
            write!(f, "\n  {}", self.read)?;
        }
        for n in &self.notes {
            write!(f, "\n  {n}")?;
        }
        Ok(())
    }
}

/// A reference trajectory in local metres, ready for matching with the samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// The file, as errors name it.
    pub file: String,
    /// Its format.
    pub format: Format,
    /// The time scale of the epochs' `t`.
    pub time: TimeScale,
    /// The used epochs, times strictly increasing.
    pub epochs: Vec<LocalEpoch>,
    /// The local plane's origin (receiver logs).
    pub origin: Option<Geodetic>,
    /// How many epochs the origin averages (0 for a given origin or a CSV).
    pub origin_epochs: usize,
    /// GPS - UTC (s) in messages: the one given, else the table's at the first epoch.
    pub leap_seconds: i32,
    /// What was used and left out.
    pub report: UseReport,
    /// For a trajectory: samples' `t` = stamp + this (s) when given (`--time-offset`).
    pub time_offset: Option<f64>,
    /// For a trajectory: the clock rate (ppm) when given (`--clock-ppm`).
    pub clock_ppm: Option<f64>,
    /// For a trajectory: each epoch's yaw (rad, counter-clockwise, unwrapped), as read.
    pub yaw: Vec<f64>,
}

/// Reads a reference file of any format.
pub fn load(path: &Path, o: &ReferenceOptions) -> Result<Reference> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    load_bytes(path, &bytes, o)
}

/// Reads the content `bytes` of the reference file `path` (already in memory) as [`load`]
/// reads the file: the same reference, the same warnings.
pub fn load_bytes(path: &Path, bytes: &[u8], o: &ReferenceOptions) -> Result<Reference> {
    let r = parse(&path.display().to_string(), bytes, o)?;
    for w in &r.report.read.warnings {
        eprintln!("warning: {w}");
    }
    Ok(r)
}

/// [`load_bytes`] of an NMEA log whose lines `read` has read as they were appended to
/// `bytes` ([`nmea::LogLines`]): the same reference and warnings, with only the dating of
/// the last epochs left to do. Another format is read whole.
pub fn load_read(
    path: &Path,
    bytes: &[u8],
    read: nmea::LogLines,
    o: &ReferenceOptions,
) -> Result<Reference> {
    let r = parse_read(&path.display().to_string(), bytes, read, o)?;
    for w in &r.report.read.warnings {
        eprintln!("warning: {w}");
    }
    Ok(r)
}

/// [`parse`] of an NMEA log whose lines `read` has read as they were appended to `bytes`
/// ([`nmea::LogLines`]): the same reference, with only the dating of the last epochs left to
/// do.
/// When `read` took every byte (as text), neither they nor their format are read again
/// ([`nmea::LogLines::format`]). Another format is read whole.
pub fn parse_read(
    file: &str,
    bytes: &[u8],
    read: nmea::LogLines,
    o: &ReferenceOptions,
) -> Result<Reference> {
    let format = match o.format.or_else(|| read.format(bytes)) {
        Some(f) => f,
        None => match std::str::from_utf8(bytes) {
            Ok(text) => detect_format(bytes, text),
            Err(_) => return parse(file, bytes, o),
        },
    };
    if format != Format::Nmea {
        return parse(file, bytes, o);
    }
    let log = read.finish(file, bytes, o.leap_seconds)?;
    Reference::from_log(file, Format::Nmea, log, o)
}

/// Parses a reference file's content; `file` names it in messages.
pub fn parse(file: &str, bytes: &[u8], o: &ReferenceOptions) -> Result<Reference> {
    // NMEA logs may carry binary messages between the sentences: those lines are counted
    // as corrupt, the rest is read (the strict check first: it is the faster one).
    let text = match std::str::from_utf8(bytes) {
        Ok(t) => std::borrow::Cow::Borrowed(t),
        Err(_) => String::from_utf8_lossy(bytes),
    };
    let format = o.format.unwrap_or_else(|| detect_format(bytes, &text));
    match format {
        Format::Csv => {
            let rows = csvio::parse_reference(file, &text)?;
            Ok(Reference::from_csv(file, rows))
        }
        Format::Nmea => {
            let log = nmea::parse(file, &text, o.leap_seconds)?;
            Reference::from_log(file, format, log, o)
        }
        Format::Rtklib => {
            let log = rtklib::parse(file, &text, o.leap_seconds)?;
            Reference::from_log(file, format, log, o)
        }
        Format::Tum => {
            let poses = tum::parse(file, &text)?;
            Ok(Reference::from_trajectory(
                file,
                format,
                &poses,
                Vec::new(),
                o,
            ))
        }
        Format::Mcap => {
            let (poses, note) = mcap_pose::parse(file, bytes, &o.mcap)?;
            Ok(Reference::from_trajectory(
                file,
                format,
                &poses,
                vec![note],
                o,
            ))
        }
        Format::Ubx => {
            let log = ubx::parse(file, bytes, o.leap_seconds)?;
            Reference::from_log(file, format, log, o)
        }
    }
}

impl Reference {
    /// A REFERENCE CSV's rows, used as they are.
    pub fn from_csv(file: &str, rows: Vec<RefPoint>) -> Self {
        let epochs: Vec<LocalEpoch> = rows
            .iter()
            .map(|r| LocalEpoch {
                t: r.t,
                x: r.x,
                y: r.y,
                up: None,
                heading: r.heading,
                sigma_east_north: r.sigma_h.map(|s| [s / 2f64.sqrt(); 2]),
                fix: FixQuality::RtkFixed,
                line: 0,
            })
            .collect();
        Self {
            file: file.to_string(),
            format: Format::Csv,
            time: TimeScale::Samples,
            report: UseReport {
                epochs: epochs.len(),
                used: epochs.len(),
                ..UseReport::default()
            },
            epochs,
            origin: None,
            origin_epochs: 0,
            leap_seconds: gps_time::DEFAULT_LEAP_SECONDS,
            time_offset: None,
            clock_ppm: None,
            yaw: Vec::new(),
        }
    }

    /// A trajectory's poses (TUM, MCAP), in its own frame and on its own clock: the marker's
    /// headings turned by its yaw offset from the chassis axis
    /// ([`trajectory::marker_yaw_offset`]), or left out when too few straights show it;
    /// `notes` are what the reader found, to which this adds the yaw's.
    pub fn from_trajectory(
        file: &str,
        format: Format,
        poses: &[trajectory::TrajectoryPose],
        mut notes: Vec<String>,
        o: &ReferenceOptions,
    ) -> Self {
        let mut epochs = trajectory::epochs(poses);
        let mut yaw: Vec<f64> = Vec::with_capacity(poses.len());
        for p in poses {
            let y = trajectory::yaw(p.orientation).unwrap_or(0.0);
            yaw.push(match yaw.last() {
                Some(prev) => prev + trajectory::wrap(y - prev),
                None => y,
            });
        }
        match trajectory::marker_yaw_offset(&epochs) {
            Some((offset, n)) => {
                for e in &mut epochs {
                    e.heading = e.heading.map(|h| trajectory::wrap(h + offset));
                }
                notes.push(format!(
                    "headings: the marker's yaw, turned by {:+.3} deg to the direction of travel on {n} straight chords of {} m",
                    offset.to_degrees(),
                    trajectory::YAW_CHORD
                ));
            }
            None => {
                for e in &mut epochs {
                    e.heading = None;
                }
                notes.push(format!(
                    "headings not used: fewer than {} straight chords of {} m to align the marker's yaw with the chassis axis",
                    trajectory::YAW_MIN_CHORDS,
                    trajectory::YAW_CHORD
                ));
            }
        }
        let leap_seconds = o.leap_seconds.unwrap_or_else(|| {
            gps_time::leap_seconds_at_gps(
                epochs[0].t - UNIX_TO_GPS + f64::from(gps_time::DEFAULT_LEAP_SECONDS),
            )
        });
        Self {
            file: file.to_string(),
            format,
            time: TimeScale::Trajectory,
            report: UseReport {
                epochs: epochs.len(),
                used: epochs.len(),
                notes,
                ..UseReport::default()
            },
            epochs,
            origin: None,
            origin_epochs: 0,
            leap_seconds,
            time_offset: o.time_offset,
            clock_ppm: o.clock_ppm,
            yaw,
        }
    }

    /// Keeps a log's epochs of the required fix quality and puts them into the local plane.
    /// Fails, naming what was left out, when no epoch is left.
    pub fn from_log(
        file: &str,
        format: Format,
        log: GeodeticLog,
        o: &ReferenceOptions,
    ) -> Result<Self> {
        let mut report = UseReport {
            epochs: log.epochs.len(),
            read: log.report,
            ..UseReport::default()
        };
        let used: Vec<Epoch> = log
            .epochs
            .into_iter()
            .filter(|e| {
                let ok = o.min_fix.accepts(e.fix);
                if !ok {
                    *report.below_min_fix.entry(e.fix).or_default() += 1;
                }
                ok
            })
            .collect();
        report.used = used.len();
        if used.is_empty() {
            bail!(
                "{file}: no epoch has the required fix quality (--min-fix {:?}): {report}",
                o.min_fix
            );
        }
        let (origin, origin_epochs) = choose_origin(&used, o.origin);
        let frame = LocalFrame::new(origin);
        let mut epochs: Vec<LocalEpoch> = Vec::with_capacity(used.len());
        for chunk in used.chunks(nmea::CANCEL_CHECK_EPOCHS) {
            check_this_thread()?;
            epochs.extend(chunk.iter().map(|e| {
                let [x, y, up] = frame.to_enu(&e.position);
                LocalEpoch {
                    t: e.gps_time,
                    x,
                    y,
                    up: Some(up),
                    heading: e.heading,
                    sigma_east_north: e.sigma_north_east_up.map(|s| [s[1], s[0]]),
                    fix: e.fix,
                    line: e.line,
                }
            }));
        }
        let leap_seconds = o.leap_seconds.unwrap_or_else(|| {
            epochs.first().map_or(gps_time::DEFAULT_LEAP_SECONDS, |e| {
                gps_time::leap_seconds_at_gps(e.t)
            })
        });
        Ok(Self {
            file: file.to_string(),
            format,
            time: TimeScale::Gps,
            epochs,
            origin: Some(origin),
            origin_epochs,
            leap_seconds,
            report,
            time_offset: None,
            clock_ppm: None,
            yaw: Vec::new(),
        })
    }

    /// The median over the used epochs of the horizontal RMS sigma `hypot(sigma_east, sigma_north)`
    /// (m) the log reports (GST, `.pos` sdn/sde), when it reports any: what
    /// `--reference-sigma` means.
    pub fn median_horizontal_sigma(&self) -> Option<f64> {
        let mut v: Vec<f64> = self
            .epochs
            .iter()
            .filter_map(|e| e.sigma_east_north.map(|s| s[0].hypot(s[1])))
            .filter(|s| s.is_finite())
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }

    /// The time span (s) on the reference's own scale.
    pub fn span(&self) -> (f64, f64) {
        (
            self.epochs.first().map_or(f64::NAN, |e| e.t),
            self.epochs.last().map_or(f64::NAN, |e| e.t),
        )
    }

    /// The GPS time (s) to subtract from a receiver log's epochs (GPS times `first` .. `last`)
    /// to put them on the samples' time base ([`Reference::ref_points`]).
    fn gps_shift(&self, first: f64, last: f64, samples: (f64, f64)) -> Result<f64> {
        let shift = if samples.0 >= gps_time::WEEK {
            0.0
        } else {
            // The week whose time of week puts the log over the samples.
            let (w, _) = gps_time::week_tow(first);
            [w, w + 1, w - 1]
                .into_iter()
                .map(|w| w as f64 * gps_time::WEEK)
                .find(|s| first - s <= samples.1 && last - s >= samples.0)
                .unwrap_or(w as f64 * gps_time::WEEK)
        };
        if !(first - shift <= samples.1 && last - shift >= samples.0) {
            bail!(
                "{}: the reference does not overlap the samples in time: reference {} .. {}, \
                 samples t = {:.3} .. {:.3} s (GPS time of week, or GPS seconds) \
                 (leap seconds {}: --leap-seconds)",
                self.file,
                gps_time::describe(first, self.leap_seconds),
                gps_time::describe(last, self.leap_seconds),
                samples.0,
                samples.1,
                self.leap_seconds
            );
        }
        Ok(shift)
    }

    /// A trajectory's clock offset (s; samples' `t` = stamp + offset), given the samples'
    /// first and last time: `--time-offset` when given; else 0 when the stamps overlap the
    /// samples as they are; else, for stamps that read as Unix time (beyond 1e8 s), UTC made
    /// GPS (with the leap seconds) and put on the samples' time base as a receiver log is.
    /// Fails, naming both ranges, when they still do not overlap.
    pub fn trajectory_offset(&self, samples: (f64, f64)) -> Result<f64> {
        let (first, last) = self.span();
        let overlaps = |o: f64| first + o <= samples.1 && last + o >= samples.0;
        if let Some(o) = self.time_offset {
            if overlaps(o) {
                return Ok(o);
            }
        } else if overlaps(0.0) {
            return Ok(0.0);
        } else if first > 1e8 {
            let g = f64::from(self.leap_seconds) - UNIX_TO_GPS;
            if let Ok(shift) = self.gps_shift(first + g, last + g, samples) {
                return Ok(g - shift);
            }
        }
        bail!(
            "{}: the trajectory does not overlap the samples in time: stamps {:.3} .. {:.3} s{}, \
             samples t = {:.3} .. {:.3} s; give the samples' t minus the stamp as --time-offset",
            self.file,
            first,
            last,
            self.time_offset
                .map_or(String::new(), |o| format!(" (+ --time-offset {o})")),
            samples.0,
            samples.1
        )
    }

    /// A trajectory's clock against the samples' and a line saying how it was found: both
    /// given (`--time-offset` checked by [`Reference::trajectory_offset`], `--clock-ppm` or 0
    /// with it); else estimated ([`clock::estimate`]), fixing what is given.
    pub fn clock(&self, samples: &[Sample], span: (f64, f64)) -> Result<(clock::ClockFit, String)> {
        let s_mid = 0.5 * (self.span().0 + self.span().1);
        if let (Some(_), Some(ppm)) = (self.time_offset, self.clock_ppm) {
            let offset = self.trajectory_offset(span)?;
            let fit = clock::ClockFit {
                offset,
                offset_se: 0.0,
                ppm,
                ppm_se: 0.0,
                s_mid,
                coarse: None,
                points: 0,
                windows: 0,
                straights: 0,
            };
            let how = format!(
                "clock (given): samples' t = stamp {offset:+.6} s {ppm:+.3} ppm x (stamp - {s_mid:.3} s)"
            );
            return Ok((fit, how));
        }
        if self.time_offset.is_some() {
            // A given offset must put the trajectory over the samples.
            self.trajectory_offset(span)?;
        }
        let poses: Vec<clock::StampedYaw> = self
            .epochs
            .iter()
            .zip(&self.yaw)
            .map(|(e, &yaw)| clock::StampedYaw {
                s: e.t,
                x: e.x,
                y: e.y,
                yaw,
            })
            .collect();
        let fixed = clock::ClockFixed {
            offset: self.time_offset,
            ppm: self.clock_ppm,
        };
        let fit = clock::estimate(samples, &poses, fixed)
            .map_err(|e| anyhow!("{}: clock: {e}", self.file))?;
        let how = format!(
            "clock (estimated from the turning and the straights, {} poses in {} windows, {} straight{}): \
             samples' t = stamp {:+.6} s (se {:.6} s) {:+.3} ppm (se {:.3} ppm) x (stamp - {:.3} s)",
            fit.points,
            fit.windows,
            fit.straights,
            fit.coarse
                .map_or(String::new(), |c| format!(", coarse offset {c:+.3} s")),
            fit.offset,
            fit.offset_se,
            fit.ppm,
            fit.ppm_se,
            fit.s_mid
        );
        let how = if fit.ppm_se > clock::RATE_SE_NOTE {
            format!(
                "{how}\n  the clock rate is poorly determined (se {:.0} ppm, above {:.0}): when both clocks \
                 are quartz (the unit on its HSE crystal), --clock-ppm 0 errs less; a rate error \
                 scales the distances, and so the diameters, by as much",
                fit.ppm_se,
                clock::RATE_SE_NOTE
            )
        } else {
            how
        };
        Ok((fit, how))
    }

    /// The reference rows for these samples: a trajectory (TUM, MCAP) put on the samples'
    /// clock ([`Reference::trajectory_offset`]) and interpolated at their instants
    /// ([`trajectory::resample`]), with a line saying what was matched; any other reference
    /// as [`Reference::ref_points`] gives it, with no line.
    pub fn points_for(&self, samples: &[Sample]) -> Result<(Vec<RefPoint>, Option<String>)> {
        self.points_and_clock(samples).map(|(p, line, _)| (p, line))
    }

    /// A trajectory's rows at the sample instants on the clock `clock` rather than its own
    /// estimate ([`trajectory::resample`] as [`Reference::points_and_clock`] uses it); empty
    /// for any other reference.
    pub fn points_on_clock(&self, samples: &[Sample], clock: &clock::ClockFit) -> Vec<RefPoint> {
        if self.time != TimeScale::Trajectory {
            return Vec::new();
        }
        let times: Vec<f64> = samples.iter().map(|s| s.t).collect();
        trajectory::resample(&self.epochs, |s| clock.map(s), &times).0
    }

    /// [`Reference::points_for`] with a trajectory's clock ([`Reference::clock`]).
    pub fn points_and_clock(
        &self,
        samples: &[Sample],
    ) -> Result<(Vec<RefPoint>, Option<String>, Option<clock::ClockFit>)> {
        let span = (
            samples.first().map_or(f64::NAN, |s| s.t),
            samples.last().map_or(f64::NAN, |s| s.t),
        );
        if self.time != TimeScale::Trajectory {
            return Ok((self.ref_points(span)?, None, None));
        }
        let (clock, how) = self.clock(samples, span)?;
        let times: Vec<f64> = samples.iter().map(|s| s.t).collect();
        let (points, r) = trajectory::resample(&self.epochs, |s| clock.map(s), &times);
        let line = format!(
            "{how}\n  {} reference points interpolated at the {} sample instants inside the \
             trajectory; {} instants in {} gaps left out",
            points.len(),
            r.inside,
            r.in_gaps,
            r.gaps
        );
        Ok((points, Some(line), Some(clock)))
    }

    /// The epochs as the calibration's reference rows, on the samples' time base, given the
    /// samples' first and last time (s). A CSV passes as it is. For a receiver log the samples'
    /// `t` is GPS time of week (as `record` writes it) or, when it starts beyond a week, GPS
    /// seconds since 1980-01-06; a log that crosses the end of a week continues past
    /// 604,800 s. Fails,
    /// naming both ranges, when the log and the samples do not overlap in time.
    pub fn ref_points(&self, samples: (f64, f64)) -> Result<Vec<RefPoint>> {
        let (first, last) = self.span();
        let shift = match self.time {
            TimeScale::Samples => 0.0,
            TimeScale::Gps => self.gps_shift(first, last, samples)?,
            TimeScale::Trajectory => -self.trajectory_offset(samples)?,
        };
        Ok(self
            .epochs
            .iter()
            .map(|e| RefPoint {
                t: e.t - shift,
                x: e.x,
                y: e.y,
                heading: e.heading,
                sigma_h: e
                    .sigma_east_north
                    .map(|s| s[0].hypot(s[1]))
                    .filter(|s| s.is_finite() && *s > 0.0),
            })
            .collect())
    }
}

/// Unix time minus GPS time (s) without the leap seconds: 1980-01-06 in Unix seconds.
pub const UNIX_TO_GPS: f64 = 315_964_800.0;

/// The origin and how many epochs it averages (0 when given).
fn choose_origin(used: &[Epoch], choice: OriginChoice) -> (Geodetic, usize) {
    let first = used[0].position;
    match choice {
        OriginChoice::Given(g) => (g, 0),
        OriginChoice::FirstEpoch => (first, 1),
        OriginChoice::OpeningStandstill => {
            let frame = LocalFrame::new(first);
            let mut sum = [0.0; 3];
            let mut n = 0usize;
            for e in used {
                let p = frame.to_enu(&e.position);
                if p[0].hypot(p[1]) > STANDSTILL_RADIUS {
                    break;
                }
                for k in 0..3 {
                    sum[k] += p[k];
                }
                n += 1;
            }
            let mean = sum.map(|s| s / n as f64);
            (frame.to_geodetic(mean), n)
        }
    }
}

/// Where the antenna is, given the chassis centre and heading: centre + R(heading) (forward,
/// left), heading clockwise from +y (north), x east (m).
pub fn antenna_position(x: f64, y: f64, heading: f64, forward: f64, left: f64) -> (f64, f64) {
    let (s, c) = heading.sin_cos();
    // Forward is (sin h, cos h); left is forward turned 90 degrees anticlockwise: (-cos h, sin h).
    (x + forward * s - left * c, y + forward * c + left * s)
}

/// Parses `FORWARD,LEFT` (m), as `--antenna` takes it.
pub fn parse_antenna(s: &str) -> Result<(f64, f64)> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [f, l] = parts[..] else {
        bail!("--antenna `{s}`: expected FORWARD,LEFT (metres from the axle centre)");
    };
    let num = |v: &str| -> Result<f64> {
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite() && x.abs() < 100.0)
            .ok_or_else(|| anyhow!("--antenna `{s}`: `{v}` is not a distance in metres"))
    };
    Ok((num(f)?, num(l)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn detection() {
        let table = [
            ("$GPGGA,1*00\n", Format::Nmea),
            ("\n\n junk\u{fffd}$GNRMC,x*11\n", Format::Nmea),
            (
                "\u{b5}b\u{1}\u{7}\u{fffd}\n\u{fffd}\u{fffd}\n$GNGGA,x*11\n",
                Format::Nmea,
            ),
            ("% program : RTKPOST\n", Format::Rtklib),
            ("%\n%  GPST latitude(deg)\n", Format::Rtklib),
            // Binary data before an NMEA log that happens to start with `%`.
            ("%\u{fffd}\u{1}b\u{fffd}\n$GNGGA,x*11\n", Format::Nmea),
            ("%\u{b5}\u{62}$GNRMC,x*11\n", Format::Nmea),
            ("%\u{1}\u{2}\n%\u{fffd}\n$GPZDA,x*11\n", Format::Nmea),
            (
                "2024/02/04 00:00:00.000 49.2 16.6 300 1 12 0.01 0.01 0.02 0 0 0 1.0 99.9\n",
                Format::Rtklib,
            ),
            (
                "2300 18.000 49.2 16.6 300 1 12 0.01 0.01 0.02 0 0 0 1.0 99.9\n",
                Format::Rtklib,
            ),
            ("# comment\nt,x,y\n0,0,0\n", Format::Csv),
            ("t,x,y,heading\n", Format::Csv),
            (
                "# timestamp tx ty tz qx qy qz qw\n1.5 1 2 3 0 0 0 1\n",
                Format::Tum,
            ),
            ("1700000000.1\t1 2 3 0 0 0.1 0.99\n", Format::Tum),
            ("1 2 3 4 5 6 7\n", Format::Csv),
            ("", Format::Csv),
        ];
        for (text, f) in table {
            assert_eq!(detect(text), f, "{text:?}");
        }
    }

    #[test]
    fn fix_filter() {
        use FixQuality::*;
        let all = [RtkFixed, RtkFloat, Ppp, Dgps, Sbas, Single, Invalid];
        let n = |m: MinFix| all.iter().filter(|q| m.accepts(**q)).count();
        assert_eq!(
            (n(MinFix::Fixed), n(MinFix::Float), n(MinFix::Any)),
            (1, 2, 6)
        );
    }

    #[test]
    fn lever_arm_table() {
        // (heading, forward, left) -> antenna offset (east, north).
        let table = [
            (0.0, 1.0, 0.0, (0.0, 1.0)),
            (0.0, 0.0, 1.0, (-1.0, 0.0)),
            (FRAC_PI_2, 1.0, 0.0, (1.0, 0.0)),
            (FRAC_PI_2, 0.0, 1.0, (0.0, 1.0)),
            (std::f64::consts::PI, 0.35, 0.1, (0.1, -0.35)),
            (-FRAC_PI_2, 0.35, -0.2, (-0.35, 0.2)),
        ];
        for (h, f, l, (e, n)) in table {
            let (x, y) = antenna_position(10.0, -5.0, h, f, l);
            assert!(
                (x - 10.0 - e).abs() < 1e-12 && (y + 5.0 - n).abs() < 1e-12,
                "{h} {f} {l}: {x} {y}"
            );
        }
        assert_eq!(parse_antenna("0.35,-0.1").unwrap(), (0.35, -0.1));
        for bad in ["0.35", "a,0", "0,inf", "1,2,3"] {
            assert!(parse_antenna(bad)
                .unwrap_err()
                .to_string()
                .contains("--antenna"));
        }
    }

    fn epoch(t: f64, north_m: f64, fix: FixQuality) -> Epoch {
        Epoch {
            gps_time: t,
            position: Geodetic {
                lat_deg: 49.2 + north_m / 111_200.0,
                lon_deg: 16.6,
                height: 300.0,
            },
            heading: None,
            sigma_north_east_up: Some([0.01, 0.02, 0.03]),
            fix,
            line: 1 + t as usize,
        }
    }

    #[test]
    fn filtering_origin_and_report() {
        use FixQuality::*;
        let w = 2300.0 * gps_time::WEEK;
        // Standstill 0, +0.01, -0.01 m, then moving north 1 m per epoch; a float and a single.
        let log = GeodeticLog {
            epochs: vec![
                epoch(w + 100.0, 0.0, RtkFixed),
                epoch(w + 100.1, 0.01, RtkFixed),
                epoch(w + 100.2, -0.01, RtkFixed),
                epoch(w + 100.3, 1.0, RtkFloat),
                epoch(w + 100.4, 2.0, RtkFixed),
                epoch(w + 100.5, 3.0, Single),
            ],
            report: ReadReport::default(),
        };
        let o = ReferenceOptions::default();
        let r = Reference::from_log("r.nmea", Format::Nmea, log.clone(), &o).unwrap();
        assert_eq!((r.report.epochs, r.report.used), (6, 4));
        assert_eq!(r.report.below_min_fix[&RtkFloat], 1);
        assert_eq!(r.report.below_min_fix[&Single], 1);
        assert_eq!(r.origin_epochs, 3);
        // The standstill's mean is the origin: its epochs sum to zero north.
        let ys: Vec<f64> = r.epochs.iter().map(|e| e.y).collect();
        assert!(ys[..3].iter().sum::<f64>().abs() < 1e-6, "{ys:?}");
        assert!((ys[3] - 2.0).abs() < 0.01, "{ys:?}");
        assert_eq!(r.epochs[0].sigma_east_north, Some([0.02, 0.01]));
        assert_eq!(r.median_horizontal_sigma(), Some(0.02f64.hypot(0.01)));
        let text = r.report.to_string();
        assert!(
            text.contains("6 epochs read, 4 used") && text.contains("1 RTK float"),
            "{text}"
        );

        let float = ReferenceOptions {
            min_fix: MinFix::Float,
            origin: OriginChoice::FirstEpoch,
            ..o.clone()
        };
        let r = Reference::from_log("r.nmea", Format::Nmea, log.clone(), &float).unwrap();
        assert_eq!((r.report.used, r.origin_epochs), (5, 1));
        assert_eq!(r.epochs[0].y.abs(), 0.0);

        let only_single = GeodeticLog {
            epochs: vec![epoch(w, 0.0, Single)],
            report: ReadReport::default(),
        };
        let e = Reference::from_log("r.nmea", Format::Nmea, only_single, &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("r.nmea: no epoch") && e.contains("1 single"),
            "{e}"
        );
    }

    #[test]
    fn time_alignment_and_refusal() {
        let w = 2300.0 * gps_time::WEEK;
        let log = GeodeticLog {
            epochs: vec![
                epoch(w - 0.2, 0.0, FixQuality::RtkFixed),
                epoch(w - 0.1, 1.0, FixQuality::RtkFixed),
                epoch(w, 2.0, FixQuality::RtkFixed),
                epoch(w + 0.1, 3.0, FixQuality::RtkFixed),
            ],
            report: ReadReport::default(),
        };
        let r = Reference::from_log("r.pos", Format::Rtklib, log, &ReferenceOptions::default())
            .unwrap();
        // Samples in time of week of week 2299: the log continues past 604,800 s.
        let p = r
            .ref_points((gps_time::WEEK - 1.0, gps_time::WEEK + 1.0))
            .unwrap();
        for (p, t) in p.iter().zip([604_799.8, 604_799.9, 604_800.0, 604_800.1]) {
            assert!((p.t - t).abs() < 1e-6, "{p:?}");
        }
        // Samples in GPS seconds.
        let p = r.ref_points((w - 10.0, w + 10.0)).unwrap();
        assert_eq!(p[2].t, w);
        // Samples that started after the week's end (time of week of week 2300).
        let p = r.ref_points((0.0, 5.0)).unwrap();
        assert!((p[3].t - 0.1).abs() < 1e-6, "{p:?}");
        // No overlap: both ranges named.
        let e = r.ref_points((1000.0, 2000.0)).unwrap_err().to_string();
        assert!(
            e.contains("does not overlap")
                && e.contains("GPS week 2299 TOW 604799.800")
                && e.contains("1000.000 .. 2000.000"),
            "{e}"
        );
    }

    #[test]
    fn csv_passes_through() {
        let r = parse(
            "r.csv",
            b"t,x,y,heading\n0,1,2,0.5\n0.1,1.5,2,\n",
            &ReferenceOptions::default(),
        )
        .unwrap();
        assert_eq!(
            (r.format, r.time, r.report.used),
            (Format::Csv, TimeScale::Samples, 2)
        );
        let p = r.ref_points((100.0, 200.0)).unwrap();
        assert_eq!(
            p,
            csvio::parse_reference("r.csv", "t,x,y,heading\n0,1,2,0.5\n0.1,1.5,2,\n").unwrap()
        );
    }
}
