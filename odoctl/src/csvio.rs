//! The SAMPLES and REFERENCE CSV files (fixed formats: other tools depend on them).
//!
//! * SAMPLES: header row; columns `t` (s), `left`, `right` (absolute increment counts of wheel
//!   1 and 2, integers); optional `left_index`, `right_index` (counts latched at each wheel's
//!   last index pulse, empty when unknown) and the unit's own record (`seq`, `x`, `y`,
//!   `heading`, `sigma_x`, `sigma_y`, `sigma_heading`, `cov_xy`, `flags`); other columns are
//!   ignored. The first row is the starting point; each later row integrates the counts since
//!   the previous row. The reader also takes [`COV_XY_ALIAS`] for `cov_xy`.
//! * REFERENCE: header row; `t`, `x`, `y` (m, x east, y north), optional `heading` (rad,
//!   clockwise from +y) and `sigma_h` (the row's horizontal RMS noise, m, as a receiver's GST
//!   or `.pos` sigmas give it; the uncertainty fit uses it instead of `--reference-sigma`). Rows are matched to samples by equal `t` within [`MATCH_TOLERANCE`].
//!
//! Columns are found by their header name, in any order. Blank lines and lines starting with
//! `#` are skipped. A leading UTF-8 byte-order mark is ignored, and fields may be quoted as
//! spreadsheets save them (RFC 4180: `"1.5"`, `"a,b"`, `""` for a quote; within one line). Time must increase strictly from row to row. Every error names the file and
//! the line.

use std::fmt::Write as _;
use std::io::Write;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use crate::text::{excerpt, excerpt_n};

/// Samples and reference points are matched when their times differ by at most this (s).
pub const MATCH_TOLERANCE: f64 = 1.0e-3;

/// The SAMPLES columns every writer writes: time, the two absolute counts, the index latches
/// (the reader needs the first three).
pub const SAMPLE_COLUMNS: [&str; 5] = ["t", "left", "right", "left_index", "right_index"];

/// The SAMPLES columns of the unit's own pose record ([`UnitPose`] and the status flags).
pub const POSE_COLUMNS: [&str; 9] = [
    "seq",
    "x",
    "y",
    "heading",
    "sigma_x",
    "sigma_y",
    "sigma_heading",
    "cov_xy",
    "flags",
];

/// Another header name of the `cov_xy` column, read as it: the name earlier versions of
/// `record` and `decode` write.
pub const COV_XY_ALIAS: &str = "sigma_xy";

/// The SAMPLES columns of the record's clocks and link counters, as `record` and `decode`
/// write them (the first three are read into [`UnitPose::time`], the ROS exports' stamps).
pub const RECORD_COLUMNS: [&str; 5] = [
    "mcu_time_us",
    "gps_week",
    "gps_tow_ms",
    "sample_in_second",
    "dropped",
];

/// Which columns a SAMPLES file carries; the one schema its writers and reader share.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SamplesLayout {
    /// [`SAMPLE_COLUMNS`] only (`simulate`).
    Counts,
    /// [`SAMPLE_COLUMNS`] and [`POSE_COLUMNS`].
    Pose,
    /// [`SAMPLE_COLUMNS`], [`POSE_COLUMNS`] and [`RECORD_COLUMNS`] (`record`, `decode`).
    Record,
}

/// The clocks and link counters of a [`SamplesLayout::Record`] row, in the order of
/// [`RECORD_COLUMNS`].
pub type RecordFields = [u64; 5];

impl SamplesLayout {
    /// The header row (without the line end).
    pub fn header(self) -> String {
        let mut cols: Vec<&str> = SAMPLE_COLUMNS.to_vec();
        if self != Self::Counts {
            cols.extend(POSE_COLUMNS);
        }
        if self == Self::Record {
            cols.extend(RECORD_COLUMNS);
        }
        cols.join(",")
    }

    /// Appends one row and its line end to `buf`: `extra` fills [`RECORD_COLUMNS`] (empty
    /// fields when `None`).
    pub fn push_row(self, buf: &mut String, s: &Sample, extra: Option<&RecordFields>) {
        let o = |v: Option<i64>| v.map(|v| v.to_string()).unwrap_or_default();
        let _ = write!(
            buf,
            "{},{},{},{},{}",
            fmt_t(s.t),
            s.left,
            s.right,
            o(s.left_index),
            o(s.right_index)
        );
        if self != Self::Counts {
            match &s.unit {
                Some(u) => {
                    let _ = write!(
                        buf,
                        ",{},{},{},{},{},{},{},{},{}",
                        u.seq.map(|v| v.to_string()).unwrap_or_default(),
                        fmt_real(u.x),
                        fmt_real(u.y),
                        fmt_real(u.heading),
                        fmt_real(u.sigma_x),
                        fmt_real(u.sigma_y),
                        fmt_real(u.sigma_heading),
                        fmt_real(u.cov_xy),
                        s.flags.map(|v| v.to_string()).unwrap_or_default()
                    );
                }
                None => buf.push_str(",,,,,,,,,"),
            }
        }
        if self == Self::Record {
            match extra {
                Some(e) => {
                    for v in e {
                        let _ = write!(buf, ",{v}");
                    }
                }
                None => buf.push_str(",,,,,"),
            }
        }
        buf.push('\n');
    }

    /// The sample [`read_samples`] gives back from the row [`Self::push_row`] writes of `s`
    /// with `extra`: the time as [`fmt_t`] writes it; without the pose columns no pose and no
    /// flags, with them the flags only beside a pose; the record's time tag from `extra`.
    pub fn read_back(self, s: &Sample, extra: Option<&RecordFields>) -> Sample {
        let mut out = Sample {
            t: fmt_t(s.t).parse().unwrap_or(s.t),
            unit: None,
            ..*s
        };
        if self == Self::Counts || s.unit.is_none() {
            out.flags = None;
            return out;
        }
        out.unit = s.unit.map(|u| UnitPose {
            time: match (self, extra) {
                (Self::Record, Some(e)) => Some(RecordTime {
                    mcu_time_us: e[0],
                    gps_week: e[1].try_into().unwrap_or(u16::MAX),
                    gps_tow_ms: e[2].try_into().unwrap_or(u32::MAX),
                }),
                _ => None,
            },
            ..u
        });
        out
    }
}

/// The unit's own pose record carried in a SAMPLES row (as `record` writes it).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UnitPose {
    /// Sequence number of the record, when known.
    pub seq: Option<u64>,
    /// x (m, east).
    pub x: f64,
    /// y (m, north).
    pub y: f64,
    /// Heading (rad, clockwise from +y, cumulative).
    pub heading: f64,
    /// sigma of x (m).
    pub sigma_x: f32,
    /// sigma of y (m).
    pub sigma_y: f32,
    /// sigma of the heading (rad).
    pub sigma_heading: f32,
    /// Covariance of x and y as the unit sends it (m^2), 0 when absent.
    pub cov_xy: f32,
    /// The record's time tag (`mcu_time_us`, `gps_week`, `gps_tow_ms`), when the file has it.
    pub time: Option<RecordTime>,
}

/// The time fields of a recorded pose record (what `record` writes after the pose columns).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordTime {
    /// MCU time of the sample, microseconds since the unit started.
    pub mcu_time_us: u64,
    /// GPS week (meaningful when the flags' time-valid bit is set).
    pub gps_week: u16,
    /// GPS time of week of the sample's second, milliseconds.
    pub gps_tow_ms: u32,
}

/// One SAMPLES row.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    /// Sample time (s).
    pub t: f64,
    /// Absolute increment count of wheel 1 (left).
    pub left: i64,
    /// Absolute increment count of wheel 2 (right).
    pub right: i64,
    /// Count latched at the left wheel's last index pulse.
    pub left_index: Option<i64>,
    /// Count latched at the right wheel's last index pulse.
    pub right_index: Option<i64>,
    /// Status flags of the record, when present.
    pub flags: Option<u64>,
    /// The unit's own pose, when the file carries it.
    pub unit: Option<UnitPose>,
}

/// One REFERENCE row.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RefPoint {
    /// Time (s).
    pub t: f64,
    /// x (m, east).
    pub x: f64,
    /// y (m, north).
    pub y: f64,
    /// Heading (rad, clockwise from +y), when the reference has one.
    pub heading: Option<f64>,
    /// Horizontal RMS noise of this position, `hypot(sigma_east, sigma_north)` (m), when the
    /// reference gives it (GST, `.pos` sigmas, a `sigma_h` column).
    pub sigma_h: Option<f64>,
}

/// A CSV table: its header, and its data rows read one after the other
/// ([`Table::each_row`]) without holding them.
struct Table<'a> {
    file: &'a str,
    header_line: usize,
    columns: Vec<String>,
    /// The text after the header row.
    body: &'a str,
}

/// Splits a line with quoted fields (RFC 4180: `"1.5"`, `"a,b"`, `""` for a quote inside a
/// quoted field; a quoted field ends on its line), each field trimmed; `Err` says what is
/// wrong with the line.
fn split_quoted(line: &str) -> Result<Vec<String>, String> {
    let blank = |c: &char| *c == ' ' || *c == '\t';
    let mut out = Vec::new();
    let mut chars = line.chars().peekable();
    loop {
        while chars.next_if(blank).is_some() {}
        let mut field = String::new();
        if chars.next_if_eq(&'"').is_some() {
            loop {
                match chars.next() {
                    None => {
                        return Err(format!(
                            "field {} has no closing quote (`\"`)",
                            out.len() + 1
                        ))
                    }
                    Some('"') if chars.next_if_eq(&'"').is_none() => break,
                    Some(c) => field.push(c),
                }
            }
            while chars.next_if(blank).is_some() {}
            if let Some(c) = chars.peek().filter(|&&c| c != ',') {
                return Err(format!(
                    "field {}: `{}` after its closing quote",
                    out.len() + 1,
                    excerpt(&c.to_string())
                ));
            }
        } else {
            while let Some(c) = chars.next_if(|&c| c != ',') {
                field.push(c);
            }
        }
        out.push(field.trim().to_owned());
        if chars.next().is_none() {
            return Ok(out);
        }
    }
}

/// A line that is not a row: blank, or a `#` comment.
fn skipped(line: &str) -> bool {
    let t = line.trim_start();
    t.is_empty() || t.starts_with('#')
}

impl<'a> Table<'a> {
    /// Reads the header (the first line that is not skipped).
    fn parse(file: &'a str, text: &'a str) -> Result<Self> {
        // A byte-order mark, as spreadsheets save UTF-8, is not part of the first column.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut offset = 0;
        for (i, raw) in text.split('\n').enumerate() {
            let next = (offset + raw.len() + 1).min(text.len());
            let line = raw.trim_end_matches('\r');
            if !skipped(line) {
                return Ok(Self {
                    file,
                    header_line: i + 1,
                    columns: split_quoted(line).map_err(|e| anyhow!("{file}:{}: {e}", i + 1))?,
                    body: &text[next..],
                });
            }
            offset = next;
        }
        bail!("{file}: empty file (no header row)")
    }

    /// A capacity for the rows: the body's lines.
    fn rows_hint(&self) -> usize {
        self.body.bytes().filter(|&b| b == b'\n').count() + 1
    }

    /// Calls `f` with each data row, in file order; a row with another number of fields than
    /// the header's, or none at all, is an error.
    fn each_row(&self, mut f: impl FnMut(Row<'_>) -> Result<()>) -> Result<()> {
        let mut fields: Vec<&str> = Vec::with_capacity(self.columns.len());
        let mut rows = 0usize;
        for (i, raw) in self.body.split('\n').enumerate() {
            let line = raw.trim_end_matches('\r');
            if skipped(line) {
                continue;
            }
            let lineno = self.header_line + 1 + i;
            // Quoted fields (rare) are unquoted into owned text; the rest are slices.
            let quoted: Vec<String>;
            let unquoted: Vec<&str>;
            let row: &[&str] = if line.contains('"') {
                quoted = split_quoted(line).map_err(|e| anyhow!("{}:{lineno}: {e}", self.file))?;
                unquoted = quoted.iter().map(String::as_str).collect();
                &unquoted
            } else {
                fields.clear();
                let mut start = 0;
                for (j, b) in line.bytes().enumerate() {
                    if b == b',' {
                        fields.push(line[start..j].trim());
                        start = j + 1;
                    }
                }
                fields.push(line[start..].trim());
                &fields
            };
            if row.len() != self.columns.len() {
                bail!(
                    "{}:{lineno}: {} fields, but the header has {} columns",
                    self.file,
                    row.len(),
                    self.columns.len()
                );
            }
            f(Row {
                file: self.file,
                line: lineno,
                fields: row,
            })?;
            rows += 1;
        }
        if rows == 0 {
            bail!(
                "{}:{}: no data rows after the header",
                self.file,
                self.header_line
            );
        }
        Ok(())
    }

    fn column<'n>(&self, name: &'n str) -> Option<Col<'n>> {
        let index = self.columns.iter().position(|c| c == name)?;
        Some(Col { name, index })
    }

    fn required<'n>(&self, name: &'n str) -> Result<Col<'n>> {
        self.column(name).ok_or_else(|| {
            anyhow!(
                "{}:{}: missing column `{name}` (header has: {})",
                self.file,
                self.header_line,
                excerpt_n(&self.columns.join(","), 80)
            )
        })
    }
}

/// A column found in the header: its name (for errors) and its position.
#[derive(Clone, Copy)]
struct Col<'n> {
    name: &'n str,
    index: usize,
}

/// A field parser: the value, or what the text is not (`"a number"`...).
type Parser<T> = fn(&str) -> Result<T, &'static str>;

/// One data row; its fields are parsed with errors naming the file, the line and the column.
struct Row<'t> {
    file: &'t str,
    line: usize,
    fields: &'t [&'t str],
}

impl Row<'_> {
    fn get<T>(&self, col: Col, parse: Parser<T>) -> Result<T> {
        let value = self.fields[col.index];
        parse(value).map_err(|what| {
            anyhow!(
                "{}:{}: column `{}`: `{}` is not {what}",
                self.file,
                self.line,
                col.name,
                excerpt(value)
            )
        })
    }

    /// The value of an optional column: `None` when the file has no such column or the field
    /// is empty.
    fn optional<T>(&self, col: Option<Col>, parse: Parser<T>) -> Result<Option<T>> {
        match col {
            Some(c) if !self.fields[c.index].is_empty() => self.get(c, parse).map(Some),
            _ => Ok(None),
        }
    }

    /// The row's time, which must be after the previous row's (`prev`, updated).
    fn time(&self, col: Col, prev: &mut Option<f64>) -> Result<f64> {
        let t = self.get(col, real)?;
        if let Some(p) = *prev {
            if t <= p {
                bail!(
                    "{}:{}: time {t} is not after the previous row's time {p} (time must increase)",
                    self.file,
                    self.line
                );
            }
        }
        *prev = Some(t);
        Ok(t)
    }
}

/// A finite `f64` or `f32`.
fn real<T: std::str::FromStr + Into<f64> + Copy>(v: &str) -> Result<T, &'static str> {
    let x: T = v.parse().map_err(|_| "a number")?;
    if !x.into().is_finite() {
        return Err("a finite number");
    }
    Ok(x)
}

/// A coordinate the unit's integrator can start from (|v| <= 2^30 m).
fn position(v: &str) -> Result<f64, &'static str> {
    let x: f64 = real(v)?;
    if x.abs() > odo_unit::odometry::integrator::MAX_POSITION {
        return Err("within +-1073741824 m (the integrator's range)");
    }
    Ok(x)
}

/// A heading the unit's integrator can start from (|v| <= 2^32 rad).
fn heading(v: &str) -> Result<f64, &'static str> {
    let h: f64 = real(v)?;
    if h.abs() > odo_unit::odometry::integrator::MAX_HEADING {
        return Err("within +-4294967296 rad (the integrator's range)");
    }
    Ok(h)
}

fn integer(v: &str) -> Result<i64, &'static str> {
    v.parse().map_err(|_| "an integer")
}

/// A non-negative integer, hexadecimal with a `0x` prefix.
fn unsigned(v: &str) -> Result<u64, &'static str> {
    let v2 = v.trim_start_matches("0x");
    if v2.len() != v.len() {
        return u64::from_str_radix(v2, 16).map_err(|_| "a hexadecimal integer");
    }
    v.parse().map_err(|_| "a non-negative integer")
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("{}: cannot read", path.display()))
}

/// Parses a SAMPLES CSV text; `file` names it in errors.
pub fn parse_samples(file: &str, text: &str) -> Result<Vec<Sample>> {
    let table = Table::parse(file, text)?;
    let [t, left, right, left_index, right_index] = SAMPLE_COLUMNS;
    let [seq, x, y, heading, sigma_x, sigma_y, sigma_heading, cov_xy, flags] = POSE_COLUMNS;
    let ct = table.required(t)?;
    let cl = table.required(left)?;
    let cr = table.required(right)?;
    let cli = table.column(left_index);
    let cri = table.column(right_index);
    let cflags = table.column(flags);
    let cseq = table.column(seq);
    let pose_cols = [x, y, heading, sigma_x, sigma_y, sigma_heading].map(|c| table.column(c));
    let has_pose = pose_cols.iter().all(Option::is_some);
    let cxy = table.column(cov_xy).or_else(|| table.column(COV_XY_ALIAS));
    let [mcu_time_us, gps_week, gps_tow_ms, _, _] = RECORD_COLUMNS;
    let time_cols = [mcu_time_us, gps_week, gps_tow_ms].map(|c| table.column(c));
    let mut out = Vec::with_capacity(table.rows_hint());
    let mut prev = None;
    table.each_row(|row| {
        let t = row.time(ct, &mut prev)?;
        let mut s = Sample {
            t,
            left: row.get(cl, integer)?,
            right: row.get(cr, integer)?,
            left_index: row.optional(cli, integer)?,
            right_index: row.optional(cri, integer)?,
            flags: row.optional(cflags, unsigned)?,
            unit: None,
        };
        if has_pose {
            let g = |i: usize| pose_cols[i].expect("checked");
            if !row.fields[g(0).index].is_empty() {
                s.unit = Some(UnitPose {
                    seq: row.optional(cseq, unsigned)?,
                    x: row.get(g(0), real)?,
                    y: row.get(g(1), real)?,
                    heading: row.get(g(2), real)?,
                    sigma_x: row.get(g(3), real)?,
                    sigma_y: row.get(g(4), real)?,
                    sigma_heading: row.get(g(5), real)?,
                    cov_xy: row.optional(cxy, real)?.unwrap_or(0.0),
                    time: match [0, 1, 2].map(|i| row.optional(time_cols[i], unsigned)) {
                        [Ok(Some(m)), Ok(Some(w)), Ok(Some(t))] => Some(RecordTime {
                            mcu_time_us: m,
                            gps_week: w.try_into().map_err(|_| {
                                anyhow!("{file}:{}: `{gps_week}` out of range", row.line)
                            })?,
                            gps_tow_ms: t.try_into().map_err(|_| {
                                anyhow!("{file}:{}: `{gps_tow_ms}` out of range", row.line)
                            })?,
                        }),
                        [m, w, t] => {
                            // Empty fields: no time tag; anything else that is not a number
                            // is an error naming the column.
                            m?;
                            w?;
                            t?;
                            None
                        }
                    },
                });
            }
        }
        out.push(s);
        Ok(())
    })?;
    Ok(out)
}

/// Reads a SAMPLES CSV file.
pub fn read_samples(path: &Path) -> Result<Vec<Sample>> {
    parse_samples(&path.display().to_string(), &read_text(path)?)
}

/// Parses a REFERENCE CSV text; `file` names it in errors.
pub fn parse_reference(file: &str, text: &str) -> Result<Vec<RefPoint>> {
    let table = Table::parse(file, text)?;
    let ct = table.required("t")?;
    let cx = table.required("x")?;
    let cy = table.required("y")?;
    let ch = table.column("heading");
    let cs = table.column("sigma_h");
    let mut out = Vec::with_capacity(table.rows_hint());
    let mut prev = None;
    table.each_row(|row| {
        out.push(RefPoint {
            t: row.time(ct, &mut prev)?,
            x: row.get(cx, position)?,
            y: row.get(cy, position)?,
            heading: row.optional(ch, heading)?,
            sigma_h: row
                .optional(cs, real)?
                .filter(|s: &f64| s.is_finite() && *s > 0.0),
        });
        Ok(())
    })?;
    Ok(out)
}

/// Reads a REFERENCE CSV file.
pub fn read_reference(path: &Path) -> Result<Vec<RefPoint>> {
    parse_reference(&path.display().to_string(), &read_text(path)?)
}

/// Pairs of (sample index, reference index) with equal times (within [`MATCH_TOLERANCE`]),
/// in increasing order; each sample is paired with its nearest reference point.
pub fn match_times(samples: &[Sample], reference: &[RefPoint]) -> Vec<(usize, usize)> {
    let mut out = Vec::with_capacity(samples.len());
    let mut j = 0;
    for (i, s) in samples.iter().enumerate() {
        while j + 1 < reference.len() && reference[j + 1].t <= s.t {
            j += 1;
        }
        let mut best: Option<usize> = None;
        for k in [j, j + 1] {
            if k < reference.len() && (reference[k].t - s.t).abs() <= MATCH_TOLERANCE {
                best = match best {
                    Some(b) if (reference[b].t - s.t).abs() <= (reference[k].t - s.t).abs() => {
                        Some(b)
                    }
                    _ => Some(k),
                };
            }
        }
        if let Some(b) = best {
            out.push((i, b));
        }
    }
    out
}

/// Like [`match_times`], but fails with a message naming both files when fewer than `min`
/// pairs exist.
pub fn match_or_fail(
    samples: &[Sample],
    samples_file: &str,
    reference: &[RefPoint],
    reference_file: &str,
    min: usize,
) -> Result<Vec<(usize, usize)>> {
    let m = match_times(samples, reference);
    if m.len() < min {
        bail!(
            "{samples_file} and {reference_file}: {} common times (within {} ms) but at least {min} are needed \
             (samples span {:.3}..{:.3} s, reference {:.3}..{:.3} s)",
            m.len(),
            MATCH_TOLERANCE * 1e3,
            samples.first().map_or(f64::NAN, |s| s.t),
            samples.last().map_or(f64::NAN, |s| s.t),
            reference.first().map_or(f64::NAN, |s| s.t),
            reference.last().map_or(f64::NAN, |s| s.t),
        );
    }
    Ok(m)
}

/// Formats a time stamp: fixed 6 decimals (microseconds).
pub fn fmt_t(t: f64) -> String {
    format!("{t:.6}")
}

/// Formats a real field: the shortest text that reads back to the same `f64` or `f32`
/// (Rust's `{:?}`: a decimal point always, an exponent for very large and small values).
pub fn fmt_real(v: impl std::fmt::Debug) -> String {
    format!("{v:?}")
}

/// Writes SAMPLES CSV in `layout` ([`SamplesLayout::Record`] rows without their clocks).
pub fn write_samples(w: &mut dyn Write, samples: &[Sample], layout: SamplesLayout) -> Result<()> {
    let mut buf = layout.header();
    buf.push('\n');
    for s in samples {
        buf.clear_if_large(w)?;
        layout.push_row(&mut buf, s, None);
    }
    w.write_all(buf.as_bytes())?;
    Ok(())
}

/// Writes REFERENCE CSV (`t,x,y[,heading]`).
pub fn write_reference(w: &mut dyn Write, reference: &[RefPoint]) -> Result<()> {
    let with_heading = reference.iter().any(|r| r.heading.is_some());
    let with_sigma = reference.iter().any(|r| r.sigma_h.is_some());
    let mut buf = String::from("t,x,y");
    if with_heading {
        buf.push_str(",heading");
    }
    if with_sigma {
        buf.push_str(",sigma_h");
    }
    buf.push('\n');
    for r in reference {
        buf.clear_if_large(w)?;
        let _ = write!(buf, "{},{},{}", fmt_t(r.t), fmt_real(r.x), fmt_real(r.y));
        if with_heading {
            let _ = write!(buf, ",{}", r.heading.map(fmt_real).unwrap_or_default());
        }
        if with_sigma {
            let _ = write!(buf, ",{}", r.sigma_h.map(fmt_real).unwrap_or_default());
        }
        buf.push('\n');
    }
    w.write_all(buf.as_bytes())?;
    Ok(())
}

/// Flushes a text buffer to a writer when it grows large.
trait Flush {
    fn clear_if_large(&mut self, w: &mut dyn Write) -> Result<()>;
}

impl Flush for String {
    fn clear_if_large(&mut self, w: &mut dyn Write) -> Result<()> {
        if self.len() > 1 << 16 {
            w.write_all(self.as_bytes())?;
            self.clear();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error of parsing `text` as `s.csv`.
    fn samples_error(text: &str) -> String {
        parse_samples("s.csv", text).unwrap_err().to_string()
    }

    #[test]
    fn samples_parse_and_errors() {
        let ok = "t,left,right,left_index\n0.0,0,0,\n0.02,10,-3,5\n";
        let s = parse_samples("s.csv", ok).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[1].right, -3);
        assert_eq!(s[1].left_index, Some(5));
        assert_eq!(s[0].left_index, None);

        let e = samples_error("t,left\n0,0\n");
        assert!(e.contains("s.csv:1") && e.contains("`right`"), "{e}");
        let e = samples_error("t,left,right\n0,0,0\n0.02,x,0\n");
        assert!(e.contains("s.csv:3") && e.contains("`left`"), "{e}");
        let e = samples_error("t,left,right\n0,0,0\n# c\n\n0,1,1\n");
        assert!(e.contains("s.csv:5") && e.contains("increase"), "{e}");
        let e = samples_error("t,left,right\n");
        assert!(e.contains("no data rows"), "{e}");
        let e = samples_error("t,left,right\n0,1\n");
        assert!(e.contains("s.csv:2"), "{e}");

        // Rows are read in file order: the first bad line is the one named, whatever is wrong
        // with a later one.
        let e = samples_error("t,left,right\n0,0,0\n0.02,x,0\n0.04,1\n");
        assert!(e.contains("s.csv:3") && e.contains("`left`"), "{e}");
        let e = samples_error("t,left,right\n0,0,0\n0.02,1\n0.04,x,0\n");
        assert!(e.contains("s.csv:3") && e.contains("2 fields"), "{e}");
    }

    /// Comments and blank lines before the header, CRLF line ends, spaces around fields, no
    /// final line end: the same rows, and errors still name the file's own line.
    #[test]
    fn samples_layout_boundaries() {
        let text =
            "# recorded 2026-11-24\r\n\r\n t , left ,right\r\n0, 1 ,2\r\n  # pause\r\n0.02,3,4";
        let s = parse_samples("s.csv", text).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!((s[0].left, s[0].right, s[1].t, s[1].right), (1, 2, 0.02, 4));
        let e = samples_error("# c\n\nt,left,right\n0,0,0\n\n0.02,0,y\n");
        assert!(e.contains("s.csv:6") && e.contains("`right`"), "{e}");
        let e = samples_error("# only a comment\n\n");
        assert!(e.contains("empty file"), "{e}");
    }

    /// As spreadsheets save a CSV: a byte-order mark, CRLF, quoted fields.
    #[test]
    fn bom_crlf_and_quoted_fields() {
        let text = "\u{feff}t,left,right\r\n0,1,2\r\n0.02,3,4\r\n";
        let s = parse_samples("s.csv", text).unwrap();
        assert_eq!((s.len(), s[0].left, s[1].t, s[1].right), (2, 1, 0.02, 4));
        // Quoted numbers, quoted header names, a quoted comma and doubled quotes in an
        // ignored column, spaces around the quotes.
        let text = "\u{feff}\"t\",\"x\",\"y\",\"note, \"\"here\"\"\"\r\n\
                    \"1.5\", \"2\" ,3,\"a,b\"\r\n\
                    2.5,\"-1.25\",4,\"say \"\"hi\"\"\"\r\n";
        let r = parse_reference("r.csv", text).unwrap();
        assert_eq!(r.len(), 2);
        assert_eq!((r[0].t, r[0].x, r[0].y), (1.5, 2.0, 3.0));
        assert_eq!((r[1].t, r[1].x, r[1].y), (2.5, -1.25, 4.0));
        assert_eq!(
            split_quoted(r#""say ""hi""", ,"a,b""#).unwrap(),
            [r#"say "hi""#, "", "a,b"]
        );
        // An unterminated quote, in a row or in the header, names the file and the line.
        let e = parse_reference("r.csv", "t,x,y\n1,2,3\n\"2,3,4\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("r.csv:3: field 1 has no closing quote"),
            "{e}"
        );
        let e = parse_reference("r.csv", "# c\nt,\"x,y\n1,2,3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("r.csv:2: field 2 has no closing quote"),
            "{e}"
        );
        let e = parse_reference("r.csv", "t,x,y\n1,\"2\"x,3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("r.csv:2: field 2: `x` after its closing quote"),
            "{e}"
        );
        // A quoted bad number is still a column error.
        let e = parse_samples("s.csv", "t,left,right\n0,\"1.5\",0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("s.csv:2") && e.contains("`left`"), "{e}");
    }

    #[test]
    fn reference_and_matching() {
        let r = parse_reference(
            "r.csv",
            "t,x,y,heading\n0.0005,1,2,0.1\n0.02,1,2,\n0.1,0,0,0\n",
        )
        .unwrap();
        assert_eq!(r[1].heading, None);
        let s = parse_samples(
            "s.csv",
            "t,left,right\n0,0,0\n0.02,0,0\n0.04,0,0\n0.1009,0,0\n",
        )
        .unwrap();
        assert_eq!(match_times(&s, &r), vec![(0, 0), (1, 1), (3, 2)]);
        let e = parse_reference("r.csv", "t,x,y\n0,1,nan\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("r.csv:2") && e.contains("`y`"), "{e}");
    }

    #[test]
    fn roundtrip() {
        let s = vec![
            Sample {
                t: 0.0,
                left: 1,
                right: 2,
                ..Default::default()
            },
            Sample {
                t: 0.02,
                left: 3,
                right: 4,
                left_index: Some(7),
                flags: Some(3),
                unit: Some(UnitPose {
                    seq: Some(9),
                    x: 0.1,
                    y: -1.0 / 3.0,
                    heading: 1e-300,
                    sigma_x: 1.5e-7,
                    cov_xy: -2.5e-9,
                    ..Default::default()
                }),
                ..Default::default()
            },
        ];
        let mut out = Vec::new();
        write_samples(&mut out, &s, SamplesLayout::Pose).unwrap();
        let back = parse_samples("x", std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(back[1], s[1]);
        assert_eq!(back[0].unit, None);
    }

    /// [`SamplesLayout::read_back`] is what the reader gives back from the written rows, in
    /// every layout, with and without a pose and the record's clocks.
    #[test]
    fn read_back_is_what_the_reader_gives() {
        let unit = UnitPose {
            seq: Some(9),
            x: 0.1,
            y: -1.0 / 3.0,
            heading: 1e-300,
            sigma_x: 1.5e-7,
            cov_xy: -2.5e-9,
            ..Default::default()
        };
        let rows = [
            (123_456.789_012_345_6, None, None),
            (123_456.809_012_345_6, Some(unit), None),
            (
                123_456.829_999_999_9,
                Some(unit),
                Some([7, 2345, 123_456_000, 41, 0]),
            ),
        ];
        for layout in [
            SamplesLayout::Counts,
            SamplesLayout::Pose,
            SamplesLayout::Record,
        ] {
            let mut text = layout.header() + "\n";
            let mut want = Vec::new();
            for (k, (t, unit, extra)) in rows.iter().enumerate() {
                let s = Sample {
                    t: *t,
                    left: -3 + k as i64,
                    right: 1 << 40,
                    left_index: Some(7),
                    right_index: None,
                    flags: Some(3),
                    unit: *unit,
                };
                layout.push_row(&mut text, &s, extra.as_ref());
                want.push(layout.read_back(&s, extra.as_ref()));
            }
            assert_eq!(parse_samples("x", &text).unwrap(), want, "{layout:?}");
        }
    }

    /// A file with the older header name of the covariance column reads as one with
    /// `cov_xy`; a file with neither reads the covariance as 0.
    #[test]
    fn cov_xy_alias() {
        let row = "0,1,2,3,0.5,-0.25,0.125,0.001,0.002,0.0003";
        let text = |cov: &str| {
            format!("t,left,right,seq,x,y,heading,sigma_x,sigma_y,sigma_heading{cov}\n{row}")
        };
        let new = parse_samples("new.csv", &(text(",cov_xy") + ",-1.5e-5\n")).unwrap();
        let old = parse_samples("old.csv", &(text(",sigma_xy") + ",-1.5e-5\n")).unwrap();
        assert_eq!(new[0].unit.unwrap().cov_xy, -1.5e-5);
        assert_eq!(old, new);
        let none = parse_samples("none.csv", &(text("") + "\n")).unwrap();
        assert_eq!(none[0].unit.unwrap().cov_xy, 0.0);
        let e = samples_error(&(text(",sigma_xy") + ",x\n"));
        assert!(e.contains("s.csv:2") && e.contains("`sigma_xy`"), "{e}");
    }

    #[test]
    fn errors_quote_binary_input_as_a_short_escaped_excerpt() {
        // A binary file where a CSV is expected: a 2 kB "field" without a comma.
        let mut text = String::from("t,x,y\n");
        text.extend(
            (0..2048u32)
                .map(|i| char::from_u32(i % 0x7f + 1).unwrap_or('?'))
                .filter(|c| !matches!(c, '\n' | '\r' | ',' | '"' | '#')),
        );
        text.push_str(",1,2\n");
        let e = parse_reference("bin.csv", &text).unwrap_err().to_string();
        assert!(e.len() < 200, "{} bytes: {e}", e.len());
        assert!(e.starts_with("bin.csv:2: column `t`"), "{e}");
        assert!(!e.chars().any(|c| c.is_control()), "{e}");
        let header = "\u{1}\u{2}".repeat(1000) + "\n1,2,3\n";
        let e = parse_reference("h.csv", &header).unwrap_err().to_string();
        assert!(e.len() < 500 && !e.chars().any(|c| c.is_control()), "{e}");
    }
}
