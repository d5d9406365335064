//! An NMEA 0183 log of the reference receiver: GGA positions, dated by RMC or ZDA, with the
//! heading of HDT and the standard deviations of GST.
//!
//! Lines end at CR LF, LF or a CR alone. A line may hold several sentences (a lost line
//! feed): each `$` followed by an address (at least three letters or digits and a `,`) starts
//! one, which ends after its `*hh` or at the next `$`; every one of them is read, and the
//! line is counted as joined. Bytes of the line outside its sentences (binary messages
//! between the sentences) are counted as stray bytes and skipped; a line without any sentence
//! is corrupt. Every sentence is checked by the firmware's sentence parser first
//! (`odo_unit::timing::nmea::parse_sentence`: `$`, `*hh` checksum, any talker), which also
//! reads RMC and ZDA (date and time, the same code as on the unit). GGA, HDT and GST are
//! read by the `nmea` crate. Other sentences are counted by type and skipped; corrupt
//! sentences (checksum, syntax) are counted and skipped; only a log with no usable epoch is
//! an error. The talkers of the checksum-valid sentences are counted.
//!
//! Times: GGA carries the UTC time of day only. Each epoch is dated by the nearest earlier
//! date (an RMC with status A, a ZDA, or the previous dated epoch), taking the day that puts
//! it within 12 hours of that date's time, so a log running over midnight gets the next
//! day; epochs before the first date sentence take its date the same way. UTC becomes GPS
//! time with the leap seconds of its date ([`gps_time::leap_seconds_on`]; a date past the
//! table's validity is warned about), or those of `--leap-seconds` for the whole log when
//! given. A leap second 23:59:60 is
//! skipped (the `nmea` crate does not represent it).
//!
//! Association: a GST belongs to the GGA of the same time of day (before or after it). An
//! HDT carries no time: it belongs to the epoch being sent, the time of the last sentence
//! that carries one (GGA, GST, RMC, ZDA), whether its GGA came before or comes after it; an
//! HDT sent first in its epoch, before any timed sentence, is taken for the previous epoch's,
//! unless the log shows that its receiver sends HDT first in every epoch (as Hemisphere
//! receivers do: see `hdt_order`); then each HDT belongs to the GGA after it. The report
//! notes the order used when the time alone cannot tell.
//! A GGA that repeats the previous epoch's time is counted and skipped; an HDT or GST that
//! went with the repeat goes to that epoch. A date sentence before the GPS epoch
//! (1980-01-06) is counted and skipped like a corrupt one.

use std::sync::Arc;

use anyhow::{bail, Result};
use chrono::Timelike;
use odo_unit::timing::nmea::{days_from_civil, parse_sentence, NmeaError, TimeMessage};

use super::geodetic::Geodetic;
use super::{gps_time, mcap_pose, ubx, FixQuality, Format, GeodeticLog, ReadReport, TextFormat};
use crate::memory::{for_drive, DRIVE_EPOCHS_PER_S};
use crate::text::{excerpt, excerpt_n, lines};

mod dating;

pub(crate) use dating::CANCEL_CHECK_EPOCHS;
use dating::{DateMark, Dating, Undated};

/// `$` + body + `*hh`: the sentence with its checksum (XOR of the body's bytes).
pub fn with_checksum(body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}")
}

/// The key of a time of day for matching GST to GGA: milliseconds.
fn ms(sod: f64) -> i64 {
    (sod * 1000.0).round() as i64
}

fn seconds_of_day(t: chrono::NaiveTime) -> f64 {
    f64::from(t.num_seconds_from_midnight()) + f64::from(t.nanosecond()) * 1e-9
}

fn fix_quality(f: Option<nmea::sentences::FixType>) -> FixQuality {
    use nmea::sentences::FixType as F;
    match f {
        Some(F::Rtk) => FixQuality::RtkFixed,
        Some(F::FloatRtk) => FixQuality::RtkFloat,
        Some(F::DGps) => FixQuality::Dgps,
        Some(F::Gps | F::Pps) => FixQuality::Single,
        _ => FixQuality::Invalid,
    }
}

/// The sentence type of a checked line: `GGA` for `$GNGGA,...`, the whole address of a
/// proprietary sentence (`PUBX`).
fn sentence_type(s: &str) -> &str {
    let address = s[1..].split(',').next().unwrap_or("");
    if address.len() == 5 && !address.starts_with('P') {
        &address[2..]
    } else {
        address
    }
}

/// Parses an NMEA log; `file` names it in messages. UTC + leap seconds = GPS time, with
/// `leap_seconds` for every epoch when given, else those of each epoch's date. Lines end at
/// CR LF, LF or CR alone.
pub fn parse(file: &str, text: &str, leap_seconds: Option<i32>) -> Result<GeodeticLog> {
    let order = hdt_order(text);
    let mut reader = LogReader::new(file, leap_seconds);
    reader.hdt_leads = order.leads;
    reader.report.notes.extend(order.note);
    reader.report.talkers = order.talkers;
    for (n, raw) in lines(text) {
        reader.line(n, raw);
    }
    reader.finish()
}

/// An NMEA log read as it grows, line by line (`record --calibrate`), by the reader of
/// [`parse`], so that at the end only the dating of its last epochs is left: an epoch is
/// dated once no later sentence can change it and a date sentence has come. HDT is read as sent
/// last in each epoch; a log whose ends show HDT sent first, a line with a line end inside
/// it, or a text that is not the lines given, is read again whole at the end
/// ([`LogLines::finish`]). A clone is the log so far, to be finished while this one reads on.
#[derive(Clone)]
pub struct LogLines {
    reader: LogReader,
    scan: HdtScan,
    /// Lines given.
    lines: usize,
    /// Their bytes with a CR LF each.
    bytes: usize,
    /// Read again whole at the end.
    whole: bool,
    /// The format of the lines given ([`super::detect`] as they come).
    format: TextFormat,
    /// A line given holds the first byte of a UBX frame's sync (0xB5).
    sync: bool,
}

impl LogLines {
    /// An empty log named `file` in messages, with `leap_seconds` as [`parse`] takes them.
    pub fn new(file: &str, leap_seconds: Option<i32>) -> Self {
        let mut reader = LogReader::new(file, leap_seconds);
        reader.undated = for_drive(DRIVE_EPOCHS_PER_S);
        reader.dating.epochs = for_drive(DRIVE_EPOCHS_PER_S);
        Self {
            reader,
            scan: HdtScan::default(),
            lines: 0,
            bytes: 0,
            whole: false,
            format: TextFormat::default(),
            sync: false,
        }
    }

    /// The next line of the log (without its line end).
    pub fn line(&mut self, raw: &str) {
        if self.whole || raw.contains(['\r', '\n']) {
            self.whole = true;
            return;
        }
        self.lines += 1;
        self.bytes += raw.len() + 2;
        self.format.line(raw);
        self.sync |= memchr::memchr(ubx::SYNC[0], raw.as_bytes()).is_some();
        self.scan.line(raw);
        self.reader.line(self.lines, raw);
        self.reader.date_settled();
    }

    /// Whether `bytes` are the lines given, each with CR LF, as far as their length tells:
    /// then every byte is in a line given as text, or its line end.
    fn took(&self, bytes: &[u8]) -> bool {
        !self.whole && bytes.len() == self.bytes
    }

    /// The format [`super::detect_format`] finds in `bytes` when they are the lines given
    /// ([`LogLines::finish`] takes them as such), known without reading them again: text (it
    /// was given as text), no MCAP magic (not text) and, where no line holds 0xB5, no UBX
    /// frame, so [`super::detect`]'s format of the lines as they came; `None` otherwise.
    pub fn format(&self, bytes: &[u8]) -> Option<Format> {
        (self.took(bytes) && !self.sync && !bytes.starts_with(mcap_pose::MAGIC))
            .then(|| self.format.format())
    }

    /// What [`parse`]`(file, text, leap_seconds)` gives, where `text` is `bytes` (the lines
    /// given, each with CR LF; bytes of another length are read whole, as UTF-8 where they
    /// are, [`String::from_utf8_lossy`]).
    pub fn finish(
        self,
        file: &str,
        bytes: &[u8],
        leap_seconds: Option<i32>,
    ) -> Result<GeodeticLog> {
        let given = self.took(bytes)
            && *self.reader.file == *file
            && self.reader.leap_seconds == leap_seconds;
        let order = self.scan.finish();
        if !given || order.leads {
            return parse(file, &String::from_utf8_lossy(bytes), leap_seconds);
        }
        let mut reader = self.reader;
        // As parse puts them: the order's note first.
        let mut notes: Vec<String> = order.note.into_iter().collect();
        notes.append(&mut reader.report.notes);
        reader.report.notes = notes;
        reader.report.talkers = order.talkers;
        reader.finish()
    }
}

/// The sentences of a line (see the module doc): each `$` starts a candidate that runs to
/// the next `$`; a candidate with an address (`$` + at least three letters or digits + `,`)
/// is a sentence, cut after its `*hh`; the rest of the line is stray bytes. Gives the
/// sentences and the number of stray bytes.
fn split_sentences(raw: &str) -> (Vec<&str>, usize) {
    let starts: Vec<usize> = raw.match_indices('$').map(|(i, _)| i).collect();
    let mut sentences = Vec::new();
    let mut stray = starts.first().copied().unwrap_or(raw.len());
    for (k, &s) in starts.iter().enumerate() {
        let end = starts.get(k + 1).copied().unwrap_or(raw.len());
        let candidate = &raw[s..end];
        let address = candidate[1..].split(',').next().unwrap_or("");
        let has_address = address.len() >= 3
            && address.len() < candidate.len() - 1
            && address.bytes().all(|b| b.is_ascii_alphanumeric());
        if !has_address {
            stray += candidate.len();
            continue;
        }
        let sentence = candidate
            .find('*')
            .and_then(|i| candidate.get(..i + 3))
            .unwrap_or(candidate);
        // Blanks between sentences are no stray bytes.
        stray += candidate[sentence.len()..].trim().len();
        sentences.push(sentence);
    }
    (sentences, stray)
}

/// The order of HDT within the log's epochs, what the report says about it, and the
/// talkers seen.
struct HdtOrder {
    talkers: std::collections::BTreeMap<String, usize>,
    /// HDT is sent before its epoch's GGA, where the time alone cannot tell: it belongs to
    /// the GGA after it.
    leads: bool,
    note: Option<String>,
}

/// Detects where HDT sits in the log's epochs. An HDT between sentences of the same time
/// belongs to that epoch; only an HDT at an epoch boundary (the timed sentences before and
/// after it carry different times) is ambiguous. For those the ends of the log decide: a log
/// that opens with an HDT (before any timed sentence) and does not end with one sends HDT
/// first in each epoch (before GGA, as Hemisphere receivers do); a log that opens with the
/// epoch's first timed sentence, or ends with an HDT, sends HDT last. Undecided: HDT is
/// taken as sent last.
fn hdt_order(text: &str) -> HdtOrder {
    let mut scan = HdtScan::default();
    for (_, raw) in lines(text) {
        scan.line(raw);
    }
    scan.finish()
}

/// [`hdt_order`] line by line: the checksum-valid sentences' talkers, and the HDT and timed
/// sentences (GGA, RMC, ZDA, GST with a time) as (type, time of day) in their order.
#[derive(Clone, Default)]
struct HdtScan {
    talkers: std::collections::BTreeMap<String, usize>,
    /// The type of the first HDT or timed sentence.
    first: Option<String>,
    /// The last of them is an HDT.
    last_hdt: bool,
    /// The last timed sentence: (type, time).
    last_timed: Option<(String, String)>,
    /// The timed sentence before an HDT that waits for the next timed one.
    waiting: Option<(String, String)>,
    /// The first HDT at a boundary: the types of the timed sentences before and after it.
    boundary: Option<(String, String)>,
}

impl HdtScan {
    /// The sentences of one line.
    fn line(&mut self, raw: &str) {
        for s in split_sentences(raw.trim()).0 {
            if checksum_ok(s) {
                self.sentence(s);
            }
        }
    }

    /// One checksum-valid sentence.
    fn sentence(&mut self, s: &str) {
        *self.talkers.entry(talker(s)).or_default() += 1;
        let kind = sentence_type(s);
        let time = match kind {
            "GGA" | "RMC" | "ZDA" | "GST" => s.split(',').nth(1).filter(|t| !t.is_empty()),
            _ => None,
        };
        if kind != "HDT" && time.is_none() {
            return;
        }
        if self.first.is_none() {
            self.first = Some(kind.to_string());
        }
        self.last_hdt = kind == "HDT";
        match time {
            None => {
                // An HDT: the first one after a timed sentence waits for the next.
                if self.boundary.is_none() && self.waiting.is_none() {
                    self.waiting.clone_from(&self.last_timed);
                }
            }
            Some(t) => {
                if let Some((p_kind, p_time)) = self.waiting.take() {
                    if p_time != t {
                        self.boundary = Some((p_kind, kind.to_string()));
                    }
                }
                if self
                    .last_timed
                    .as_ref()
                    .is_none_or(|(k, lt)| k != kind || lt != t)
                {
                    self.last_timed = Some((kind.to_string(), t.to_string()));
                }
            }
        }
    }

    /// The order found.
    fn finish(self) -> HdtOrder {
        let talkers = self.talkers;
        let Some((closer, opener)) = self.boundary else {
            return HdtOrder {
                talkers,
                leads: false,
                note: None,
            };
        };
        let first_hdt = self.first.as_deref() == Some("HDT");
        let first_opens = self.first.as_deref() == Some(opener.as_str());
        let leads = first_hdt && !self.last_hdt;
        let how = if leads {
            "HDT first in each epoch, before its GGA (the log opens with an HDT)"
        } else if first_opens || self.last_hdt {
            "HDT last in each epoch, after its GGA"
        } else {
            "HDT order undecided by the log's ends: taken as last in each epoch"
        };
        HdtOrder {
            talkers,
            leads,
            note: Some(format!(
                "heading order: {how} (HDT between {closer} and {opener}, which carry different times)"
            )),
        }
    }
}

/// The talker of sentence `s`: `GN` for `$GNGGA`, `P` + maker for a proprietary sentence
/// (`PUBX`, `PTNL`, `PSAT`), as an excerpt.
fn talker(s: &str) -> String {
    let address = s[1..].split(',').next().unwrap_or("");
    let n = if address.starts_with('P') { 4 } else { 2 };
    excerpt(address.get(..n).unwrap_or(address))
}

/// True when sentence `s` (`$...*hh`) has a valid checksum.
fn checksum_ok(s: &str) -> bool {
    let Some((body, sum)) = s.get(1..).and_then(|b| b.rsplit_once('*')) else {
        return false;
    };
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    u8::from_str_radix(sum, 16).is_ok_and(|v| v == x) && sum.len() == 2
}

/// A log being read: the GGA epochs so far, the date sentences, and the GST and HDT
/// sentences waiting for their epoch.
#[derive(Clone)]
struct LogReader {
    /// The log's name in messages.
    file: Arc<str>,
    /// GPS - UTC (s) when given (`--leap-seconds`), for the date sentences' check against the
    /// GPS epoch and the dating of every epoch; else each date's by the table.
    leap_seconds: Option<i32>,
    report: ReadReport,
    undated: Vec<Undated>,
    dates: Vec<DateMark>,
    /// The epochs of `undated` dated so far.
    dating: Dating,
    /// GSTs that came before their GGA: (time of day in ms, sigmas).
    pending_gst: Vec<(i64, [f64; 3])>,
    /// The epoch an HDT would belong to (the last GGA, until an HDT takes it).
    hdt_target: Option<usize>,
    /// Time of day (ms) of the last sentence that carries one: the epoch being sent.
    epoch_time: Option<i64>,
    /// An HDT sent in an epoch before its GGA: (time of day in ms, heading in rad, line).
    pending_hdt: Option<(i64, f64, usize)>,
    /// HDT is sent first in each epoch: it waits for the next GGA whatever its time.
    hdt_leads: bool,
}

impl LogReader {
    fn new(file: &str, leap_seconds: Option<i32>) -> Self {
        Self {
            file: file.into(),
            leap_seconds,
            report: ReadReport::default(),
            undated: Vec::new(),
            dates: Vec::new(),
            dating: Dating::default(),
            pending_gst: Vec::new(),
            hdt_target: None,
            epoch_time: None,
            pending_hdt: None,
            hdt_leads: false,
        }
    }

    /// An HDT that found no epoch: counted as unusable.
    fn drop_hdt(&mut self, p: Option<(i64, f64, usize)>) {
        let file = Arc::clone(&self.file);
        if let Some((_, _, l)) = p {
            self.report.unusable(format!(
                "{file}:{l}: HDT without a GGA of its epoch (or a second HDT): skipped"
            ));
        }
    }

    /// Reads line number `line`: each of its sentences, counting the stray bytes.
    fn line(&mut self, line: usize, raw: &str) {
        let file = Arc::clone(&self.file);
        let raw = raw.trim();
        if raw.is_empty() {
            return;
        }
        let (sentences, stray) = split_sentences(raw);
        if sentences.is_empty() {
            self.report.corrupt(format!(
                "{file}:{line}: not an NMEA sentence (no `$` and address): `{}`",
                excerpt(raw)
            ));
            return;
        }
        if stray > 0 {
            self.report.skipped_bytes += stray;
            self.report.stray_bytes(format!(
                "{file}:{line}: {stray} stray bytes besides the sentences (the sentences read)"
            ));
        }
        if sentences.len() > 1 {
            self.report.joined += 1;
        }
        for s in sentences {
            self.sentence(line, s);
        }
    }

    /// Reads sentence `s` (from its `$`) of line `line`.
    fn sentence(&mut self, line: usize, s: &str) {
        let file = Arc::clone(&self.file);
        let Some(kind) = self.checked(line, s) else {
            return;
        };
        if !matches!(kind, "GGA" | "HDT" | "GST") {
            self.report.other(kind);
            return;
        }
        let parsed = match nmea::parse_str(s) {
            Ok(p) => p,
            Err(e) => {
                let time = s.split(',').nth(1).unwrap_or("");
                if kind != "HDT" && time.get(4..6) == Some("60") {
                    self.report.unusable(format!(
                        "{file}:{line}: {kind} in a leap second ({}): skipped",
                        excerpt(time)
                    ));
                } else {
                    let e = excerpt_n(&e.to_string(), 100);
                    self.report.corrupt(format!("{file}:{line}: {kind}: {e}"));
                }
                return;
            }
        };
        match parsed {
            nmea::ParseResult::GGA(g) => self.gga(line, &g),
            nmea::ParseResult::HDT(h) => self.hdt(line, &h),
            nmea::ParseResult::GST(g) => self.gst(line, &g),
            _ => self.report.other(kind),
        }
    }

    /// The firmware's check of sentence `s`: its type when it is for the `nmea` crate to
    /// read; `None` when it is read here (a date and time: RMC, ZDA) or skipped (counted).
    fn checked<'s>(&mut self, line: usize, s: &'s str) -> Option<&'s str> {
        let file = Arc::clone(&self.file);
        let report = &mut self.report;
        match parse_sentence(s.as_bytes()) {
            Ok(TimeMessage::Rmc { valid: false, .. }) => {
                report.unusable(format!(
                    "{file}:{line}: RMC with status V (data not valid): its date is not used"
                ));
                None
            }
            Ok(m) => {
                let t = m.time();
                let sod = f64::from(t.hour) * 3600.0
                    + f64::from(t.minute) * 60.0
                    + f64::from(t.second)
                    + f64::from(t.millis) * 1e-3;
                let days = days_from_civil(i64::from(t.year), u32::from(t.month), u32::from(t.day));
                let leap = gps_time::leap_seconds_for(days, self.leap_seconds);
                if gps_time::utc_to_gps(days, sod, leap).is_err() {
                    report.corrupt(format!(
                        "{file}:{line}: {}: date before the GPS epoch (1980-01-06): skipped",
                        sentence_type(s)
                    ));
                    return None;
                }
                self.epoch_time = Some(ms(sod));
                self.dates.push(DateMark { days, sod, line });
                report.used(sentence_type(s));
                None
            }
            Err(NmeaError::BadChecksum { computed, received }) => {
                report.corrupt(format!(
                    "{file}:{line}: checksum {received:02X}, but the sentence's is {computed:02X}"
                ));
                None
            }
            Err(e @ (NmeaError::NoChecksum | NmeaError::NoStart | NmeaError::Overflow)) => {
                report.corrupt(format!("{file}:{line}: {e:?}: sentence skipped"));
                None
            }
            Err(NmeaError::Field(name)) => {
                report.unusable(format!(
                    "{file}:{line}: {}: field `{name}` missing or malformed",
                    sentence_type(s)
                ));
                None
            }
            Err(NmeaError::BadDate) => {
                report.corrupt(format!(
                    "{file}:{line}: {}: date or time out of range",
                    sentence_type(s)
                ));
                None
            }
            Err(NmeaError::Unsupported) => Some(sentence_type(s)),
        }
    }

    /// A GGA: a new epoch, with the GST and HDT that came before it.
    fn gga(&mut self, line: usize, g: &nmea::sentences::GgaData) {
        let file = Arc::clone(&self.file);
        let (Some(t), Some(lat), Some(lon), Some(alt)) =
            (g.fix_time, g.latitude, g.longitude, g.altitude)
        else {
            self.report.unusable(format!(
                "{file}:{line}: GGA without a time, position or altitude (fix quality {:?})",
                g.fix_type
            ));
            return;
        };
        let position = match (Geodetic {
            lat_deg: lat,
            lon_deg: lon,
            // Ellipsoidal = above mean sea level + geoid separation.
            height: f64::from(alt) + f64::from(g.geoid_separation.unwrap_or(0.0)),
        })
        .checked()
        {
            Ok(p) => p,
            Err(e) => {
                self.report
                    .unusable(format!("{file}:{line}: GGA position: {e}"));
                return;
            }
        };
        let sod = seconds_of_day(t);
        let sigma = self
            .pending_gst
            .iter()
            .position(|(k, _)| *k == ms(sod))
            .map(|p| self.pending_gst.swap_remove(p).1);
        self.report.used("GGA");
        self.epoch_time = Some(ms(sod));
        let mut heading = None;
        self.hdt_target = Some(self.undated.len());
        match self.pending_hdt.take() {
            Some((k, h, _)) if k == ms(sod) || self.hdt_leads => {
                heading = Some(h);
                self.hdt_target = None;
                self.report.used("HDT");
            }
            other => self.drop_hdt(other),
        }
        self.undated.push(Undated {
            sod,
            position,
            fix: fix_quality(g.fix_type),
            heading,
            sigma_north_east_up: sigma,
            line,
            date: self.dates.len().checked_sub(1),
        });
    }

    /// An HDT: the heading of the epoch being sent, or of the GGA still to come.
    fn hdt(&mut self, line: usize, h: &nmea::sentences::HdtData) {
        let file = Arc::clone(&self.file);
        let Some(deg) = h.heading.map(f64::from).filter(|d| d.is_finite()) else {
            self.report
                .unusable(format!("{file}:{line}: HDT without a heading"));
            return;
        };
        let heading = crate::stats::wrap_angle(deg.to_radians());
        if self.hdt_leads {
            // Sent first in its epoch: the next GGA's, whatever the time now.
            let old = self.pending_hdt.replace((i64::MIN, heading, line));
            self.drop_hdt(old);
            return;
        }
        match (self.hdt_target, self.epoch_time) {
            // After the GGA of the epoch being sent.
            (Some(k), Some(t)) if ms(self.undated[k].sod) == t => {
                self.undated[k].heading = Some(heading);
                self.hdt_target = None;
                self.report.used("HDT");
            }
            // Before it: waits for the GGA of that time.
            (_, Some(t)) => {
                let old = self.pending_hdt.replace((t, heading, line));
                self.drop_hdt(old);
            }
            (_, None) => self.drop_hdt(Some((0, heading, line))),
        }
    }

    /// A GST: the sigmas of the GGA of its time, before or after it.
    fn gst(&mut self, line: usize, g: &nmea::sentences::GstData) {
        let file = Arc::clone(&self.file);
        let (Some(t), Some(n), Some(e)) = (g.time, g.lat_sd, g.long_sd) else {
            self.report.unusable(format!(
                "{file}:{line}: GST without time or latitude/longitude sigmas"
            ));
            return;
        };
        let sigma = [
            f64::from(n),
            f64::from(e),
            g.alt_sd.map_or(f64::NAN, f64::from),
        ];
        let key = ms(seconds_of_day(t));
        self.epoch_time = Some(key);
        self.report.used("GST");
        let recent = self.undated.len().saturating_sub(GST_REACH);
        match self.undated[recent..]
            .iter_mut()
            .rev()
            .find(|u| ms(u.sod) == key && u.sigma_north_east_up.is_none())
        {
            Some(u) => u.sigma_north_east_up = Some(sigma),
            None => {
                if self.pending_gst.len() >= GST_REACH {
                    self.pending_gst.remove(0);
                }
                self.pending_gst.push((key, sigma));
            }
        }
    }

    /// Dates the epochs that no later sentence can change any more (all but the last
    /// [`GST_REACH`]) and are not dated yet, once there is a date sentence (their dates are
    /// then known): what [`LogReader::finish`] would do with them, done as the log is read.
    /// An error (a cancel) leaves them for later.
    fn date_settled(&mut self) {
        let settled = self.undated.len().saturating_sub(GST_REACH);
        if self.dates.is_empty() || settled < self.dating.done + DATED_TOGETHER {
            return;
        }
        let (file, leap) = (Arc::clone(&self.file), self.leap_seconds);
        let _ = self
            .dating
            .date(&file, &self.undated[..settled], &self.dates, leap);
    }

    /// The dated epochs in GPS time, once every line is read.
    fn finish(mut self) -> Result<GeodeticLog> {
        let file = Arc::clone(&self.file);
        let pending = self.pending_hdt.take();
        self.drop_hdt(pending);
        let mut report = self.report;
        if !self.undated.is_empty() && self.dates.is_empty() {
            bail!(
                "{file}: no date: {} GGA epochs but no RMC (status A) or ZDA sentence to date \
                 them (GGA carries only the time of day); {report}",
                self.undated.len()
            );
        }
        self.dating
            .date(&file, &self.undated, &self.dates, self.leap_seconds)?;
        let epochs = self.dating.finish(&mut report);
        if epochs.is_empty() {
            bail!("{file}: no usable position (no GGA with a position): {report}");
        }
        Ok(GeodeticLog { epochs, report })
    }
}

/// Epochs of a log that no later sentence changes: all but the last [`GST_REACH`] (a GST
/// finds its GGA among them; an HDT, the last).
const GST_REACH: usize = 20;

/// Settled epochs [`LogReader::date_settled`] dates at a time.
const DATED_TOGETHER: usize = 256;

#[cfg(test)]
mod tests {
    use super::*;

    /// GGA body at a time of day, with a position and quality.
    fn gga(talker: &str, time: &str, lat: &str, ns: &str, lon: &str, ew: &str, q: u8) -> String {
        with_checksum(&format!(
            "{talker}GGA,{time},{lat},{ns},{lon},{ew},{q},12,0.6,250.000,M,45.000,M,1.0,0000"
        ))
    }

    fn zda(time: &str, d: u32, m: u32, y: u32) -> String {
        with_checksum(&format!("GPZDA,{time},{d:02},{m:02},{y},00,00"))
    }

    #[test]
    fn checksum_of_a_published_sentence() {
        // The GGA example of the NMEA literature (gpsd's NMEA revealed):
        // $GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47
        assert_eq!(
            with_checksum("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
            "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
        );
        let log = format!(
            "{}\n$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\n",
            zda("123518.00", 23, 11, 2026)
        );
        let l = parse("a.nmea", &log, Some(18)).unwrap();
        let e = &l.epochs[0];
        assert!((e.position.lat_deg - (48.0 + 7.038 / 60.0)).abs() < 1e-12);
        assert!((e.position.lon_deg - (11.0 + 31.0 / 60.0)).abs() < 1e-12);
        assert!((e.position.height - 592.3).abs() < 1e-4);
        assert_eq!(e.fix, FixQuality::Single);
    }

    #[test]
    fn published_receiver_sentences() {
        // GGA and GST as printed (with their checksums) in Trimble's NMEA-0183 message
        // reference (the BD982's family); the date from a ZDA of ours.
        let log = [
            zda("172813.00", 12, 7, 2024),
            "$GPGGA,172814.0,3723.46587704,N,12202.26957864,W,2,6,1.2,18.893,M,-25.669,M,2.0,0031*4F".to_string(),
            "$GPGST,172814.0,0.006,0.023,0.020,273.6,0.023,0.020,0.031*6A".to_string(),
        ]
        .join("\r\n");
        let l = parse("t.nmea", &log, Some(18)).unwrap();
        let e = &l.epochs[0];
        assert!((e.position.lat_deg - (37.0 + 23.465_877_04 / 60.0)).abs() < 1e-12);
        assert!((e.position.lon_deg + (122.0 + 2.269_578_64 / 60.0)).abs() < 1e-12);
        assert!((e.position.height - (18.893 - 25.669)).abs() < 1e-4);
        assert_eq!(e.fix, FixQuality::Dgps);
        let s = e.sigma_north_east_up.unwrap();
        assert!(
            (s[0] - 0.023).abs() < 1e-6
                && (s[1] - 0.020).abs() < 1e-6
                && (s[2] - 0.031).abs() < 1e-6
        );
        let want = gps_time::utc_to_gps(days_from_civil(2024, 7, 12), 62_894.0, 18).unwrap();
        assert_eq!(e.gps_time, want);
        assert_eq!((l.report.corrupt, l.report.unusable), (0, 0));
    }

    #[test]
    fn hemispheres_and_talkers() {
        // (talker, N/S, E/W) -> signs.
        for (talker, ns, ew, sn, se) in [
            ("GP", "N", "E", 1.0, 1.0),
            ("GN", "S", "E", -1.0, 1.0),
            ("GL", "N", "W", 1.0, -1.0),
            ("GA", "S", "W", -1.0, -1.0),
            ("BD", "N", "E", 1.0, 1.0),
        ] {
            let log = format!(
                "{}\n{}\n",
                zda("000000.00", 1, 1, 2025),
                gga(
                    talker,
                    "000000.10",
                    "3402.50000000",
                    ns,
                    "15812.50000000",
                    ew,
                    4
                )
            );
            let l = parse("h.nmea", &log, Some(18)).unwrap();
            let p = l.epochs[0].position;
            assert!(
                (p.lat_deg - sn * (34.0 + 2.5 / 60.0)).abs() < 1e-12,
                "{talker}"
            );
            assert!(
                (p.lon_deg - se * (158.0 + 12.5 / 60.0)).abs() < 1e-12,
                "{talker}"
            );
            assert_eq!(l.epochs[0].fix, FixQuality::RtkFixed);
        }
    }

    #[test]
    fn day_rollover_dates_and_gps_time() {
        // A ZDA before midnight, epochs on both sides of it, no further date sentence; an
        // epoch before the first date is dated from it too.
        let log = [
            gga("GN", "235959.80", "4912.0", "N", "01636.0", "E", 4),
            zda("235959.90", 31, 12, 2026),
            gga("GN", "235959.90", "4912.0", "N", "01636.0", "E", 4),
            gga("GN", "000000.00", "4912.0", "N", "01636.0", "E", 4),
            gga("GN", "000000.10", "4912.0", "N", "01636.0", "E", 5),
        ]
        .join("\r\n");
        let l = parse("d.nmea", &log, Some(18)).unwrap();
        let day = days_from_civil(2026, 12, 31);
        let base = gps_time::utc_to_gps(day, 86_399.8, 18).unwrap();
        let ts: Vec<f64> = l.epochs.iter().map(|e| e.gps_time - base).collect();
        for (t, want) in ts.iter().zip([0.0, 0.1, 0.2, 0.3]) {
            assert!((t - want).abs() < 1e-6, "{ts:?}");
        }
        assert_eq!(l.epochs[3].fix, FixQuality::RtkFloat);
        // 2027-01-01 00:00:00 UTC = GPS 1,483,228,800 - 315,964,800 + 18 s.
        let midnight = gps_time::utc_to_gps(days_from_civil(2027, 1, 1), 0.0, 18).unwrap();
        assert_eq!(midnight, (1_798_761_600.0 - 315_964_800.0) + 18.0);
        assert!((l.epochs[2].gps_time - midnight).abs() < 1e-6);
        // The leap-second count moves every epoch by whole seconds.
        let l19 = parse("d.nmea", &log, Some(19)).unwrap();
        assert!((l19.epochs[2].gps_time - midnight - 1.0).abs() < 1e-6);
    }

    #[test]
    fn rmc_dates_but_not_with_status_v() {
        let rmc = |status: &str, date: &str| {
            with_checksum(&format!(
                "GNRMC,120000.00,{status},4912.0,N,01636.0,E,0.0,0.0,{date},,,R"
            ))
        };
        let log = [
            rmc("V", "010199"),
            rmc("A", "230926"),
            gga("GN", "120000.00", "4912.0", "N", "01636.0", "E", 4),
        ]
        .join("\n");
        let l = parse("r.nmea", &log, Some(18)).unwrap();
        let want = gps_time::utc_to_gps(days_from_civil(2026, 9, 23), 43_200.0, 18).unwrap();
        assert_eq!(l.epochs[0].gps_time, want);
        assert_eq!((l.report.unusable, l.report.used["RMC"]), (1, 1));
        assert!(l.report.problems[0].starts_with("r.nmea:1: RMC with status V"));
    }

    /// Found by the `reference` fuzz target: a malformed GGA whose time field has a
    /// multi-byte character across bytes 4..6 panicked slicing it (leap-second check).
    #[test]
    fn malformed_time_with_multibyte_characters_is_counted_not_a_panic() {
        let zda = zda("120000.00", 7, 1, 2026);
        for time in [
            "1234\u{FFFD}",
            "12345\u{e9}",
            "\u{e9}\u{e9}\u{e9}",
            "1200\u{1F600}",
        ] {
            let bad = gga("GP", time, "4912.0", "N", "01636.0", "E", 4);
            let good = gga("GP", "120000.00", "4912.0", "N", "01636.0", "E", 4);
            let log = format!("{zda}\r\n{bad}\r\n{good}\r\n");
            let r = parse("n.nmea", &log, Some(18)).unwrap();
            assert_eq!(r.epochs.len(), 1, "{time}");
        }
    }

    #[test]
    fn missing_date_is_an_error() {
        let log = gga("GP", "120000.00", "4912.0", "N", "01636.0", "E", 4);
        let e = parse("n.nmea", &log, Some(18)).unwrap_err().to_string();
        assert!(e.starts_with("n.nmea: no date") && e.contains("RMC"), "{e}");
    }

    #[test]
    fn corrupt_sentences_are_counted_never_fatal_unless_nothing_is_left() {
        let good = gga("GP", "120000.00", "4912.0", "N", "01636.0", "E", 4);
        let mut bad_sum = good.clone();
        bad_sum.replace_range(bad_sum.len() - 2.., "00");
        let log = [
            zda("120000.00", 23, 11, 2026),
            bad_sum.clone(),                // 2: checksum
            good.replace('*', "#"),         // 3: no checksum
            "\u{1}\u{2}binary".to_string(), // 4: no sentence
            format!(
                "xx{}",
                gga("GP", "120000.10", "4912.0", "N", "01636.0", "E", 4)
            ), // 5: junk first
            with_checksum("GPGSV,1,1,01,05,45,120,40"), // 6: other
            with_checksum("PUBX,00,1"),     // 7: proprietary
            with_checksum("GPGGA,120000.20,,,,,0,00,99.9,,M,,M,,"), // 8: no position
            with_checksum("GPGGA,120000.30,4x12.0,N,01636.0,E,4,12,0.6,250.0,M,45.0,M,,"), // 9: syntax
            good.clone(), // 10: same time as line 1's epoch? no: 12:00:00.00 again
        ]
        .join("\n");
        let l = parse("c.nmea", &log, Some(18)).unwrap();
        assert_eq!(l.epochs.len(), 1, "{:?}", l.report);
        assert_eq!(l.epochs[0].line, 5);
        // 2, 3, 4, 9 corrupt; 5 read after its stray bytes; 8 and 10 (time not after line
        // 5's) unusable.
        assert_eq!(l.report.corrupt, 4, "{}", l.report);
        assert_eq!(l.report.stray_bytes, 1, "{}", l.report);
        assert_eq!(l.report.unusable, 2, "{}", l.report);
        assert_eq!(l.report.other["GSV"], 1);
        assert_eq!(l.report.other["PUBX"], 1);
        assert!(
            l.report.problems[0].starts_with("c.nmea:2: checksum 00"),
            "{:?}",
            l.report.problems
        );
        // Nothing usable: fatal, with the report.
        let e = parse(
            "c.nmea",
            &[zda("120000.00", 23, 11, 2026), bad_sum].join("\n"),
            Some(18),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("c.nmea: no usable position") && e.contains("c.nmea:2: checksum"),
            "{e}"
        );
    }

    #[test]
    fn gst_and_hdt_association() {
        let gst = |t: &str, n: f64, e: f64| {
            with_checksum(&format!("GNGST,{t},0.5,0.02,0.01,30.0,{n},{e},0.03"))
        };
        let hdt = |h: f64| with_checksum(&format!("GNHDT,{h:.3},T"));
        let log = [
            zda("100000.00", 2, 2, 2026),
            gst("100000.00", 0.011, 0.012), // before its GGA
            gga("GN", "100000.00", "4912.0", "S", "01636.0", "W", 4),
            hdt(359.5),
            gga("GN", "100000.10", "4912.0", "S", "01636.0", "W", 4),
            gst("100000.10", 0.021, 0.022), // after its GGA
            hdt(90.0),
            hdt(91.0), // a second HDT for the same epoch: skipped
            gga("GN", "100000.20", "4912.0", "S", "01636.0", "W", 4),
        ]
        .join("\n");
        let l = parse("g.nmea", &log, Some(18)).unwrap();
        let e = &l.epochs;
        assert_eq!(
            e[0].sigma_north_east_up.map(|s| [s[0], s[1]]),
            Some([0.011f32 as f64, 0.012f32 as f64])
        );
        assert_eq!(
            e[1].sigma_north_east_up.map(|s| [s[0], s[1]]),
            Some([0.021f32 as f64, 0.022f32 as f64])
        );
        assert_eq!(e[2].sigma_north_east_up, None);
        assert!(
            (e[0].heading.unwrap() + 0.5f64.to_radians()).abs() < 1e-6,
            "{:?}",
            e[0].heading
        );
        assert!((e[1].heading.unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(e[2].heading, None);
        assert_eq!(l.report.unusable, 1);
    }

    #[test]
    fn hdt_before_its_gga_goes_with_the_epoch_being_sent() {
        let hdt = |h: f64| with_checksum(&format!("GNHDT,{h:.3},T"));
        let rmc = |t: &str| {
            with_checksum(&format!(
                "GNRMC,{t},A,4912.0,N,01636.0,E,0.0,0.0,020226,,,R"
            ))
        };
        let gga = |t: &str| gga("GN", t, "4912.0", "N", "01636.0", "E", 4);
        // Each epoch: RMC, HDT, GGA (a receiver that sends HDT before GGA).
        let log = [
            rmc("100000.00"),
            hdt(10.0),
            gga("100000.00"),
            rmc("100000.10"),
            hdt(20.0),
            gga("100000.10"),
            rmc("100000.20"),
            hdt(30.0),
            rmc("100000.30"), // the epoch of 10:00:00.20 had no GGA: its HDT is dropped
            hdt(40.0),
            gga("100000.30"),
        ]
        .join("\n");
        let l = parse("b.nmea", &log, Some(18)).unwrap();
        let deg: Vec<f64> = l
            .epochs
            .iter()
            .map(|e| (e.heading.unwrap().to_degrees() * 1000.0).round() / 1000.0)
            .collect();
        assert_eq!(deg, vec![10.0, 20.0, 40.0]);
        assert_eq!(
            (l.report.used["HDT"], l.report.unusable),
            (3, 1),
            "{}",
            l.report
        );
        assert!(l.report.problems[0].starts_with("b.nmea:8: HDT without a GGA"));
    }

    #[test]
    fn leap_second_epoch_is_skipped_and_counted() {
        let log = [
            zda("235959.00", 31, 12, 2016),
            gga("GP", "235959.50", "4912.0", "N", "01636.0", "E", 4),
            gga("GP", "235960.00", "4912.0", "N", "01636.0", "E", 4),
            gga("GP", "235960.50", "4912.0", "N", "01636.0", "E", 4),
            gga("GP", "000000.00", "4912.0", "N", "01636.0", "E", 4),
        ]
        .join("\n");
        // One leap-second count serves the whole log: 17, valid until the insertion.
        let l = parse("l.nmea", &log, Some(17)).unwrap();
        assert_eq!(l.epochs.len(), 2);
        assert_eq!(l.report.unusable, 2, "{}", l.report);
        assert!(l.report.problems[0].contains("leap second"));
        assert_eq!(l.epochs[0].gps_time, 1_167_264_016.5);
    }

    /// GPS seconds of `sod` UTC on a date with `leap` leap seconds.
    fn gps_of(y: i64, m: u32, d: u32, sod: f64, leap: i32) -> f64 {
        gps_time::utc_to_gps(days_from_civil(y, m, d), sod, leap).unwrap()
    }

    /// A log of one dated epoch at 12:00:00 UTC.
    fn noon_log(d: u32, m: u32, y: u32) -> String {
        [
            zda("120000.00", d, m, y),
            gga("GP", "120000.00", "4912.0", "N", "01636.0", "E", 4),
        ]
        .join("\n")
    }

    #[test]
    fn leap_seconds_come_from_the_date_unless_given() {
        for (y, leap) in [(2008, 14), (2014, 16), (2017, 18), (2026, 18)] {
            let l = parse("y.nmea", &noon_log(15, 3, y), None).unwrap();
            assert_eq!(
                l.epochs[0].gps_time,
                gps_of(i64::from(y), 3, 15, 43_200.0, leap)
            );
            assert!(l.report.warnings.is_empty(), "{:?}", l.report.warnings);
            // The option wins for the whole log.
            let o = parse("y.nmea", &noon_log(15, 3, y), Some(18)).unwrap();
            assert_eq!(
                o.epochs[0].gps_time,
                gps_of(i64::from(y), 3, 15, 43_200.0, 18)
            );
        }
        // The 2015 leap second: the last second of June with 16, the first of July with 17;
        // one UTC second apart, two GPS seconds apart.
        let log = [
            zda("235959.00", 30, 6, 2015),
            gga("GP", "235959.00", "4912.0", "N", "01636.0", "E", 4),
            gga("GP", "000000.00", "4912.0", "N", "01636.0", "E", 4),
        ]
        .join("\n");
        let l = parse("b.nmea", &log, None).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps_of(2015, 6, 30, 86_399.0, 16));
        assert_eq!(l.epochs[1].gps_time, gps_of(2015, 7, 1, 0.0, 17));
        assert_eq!(l.epochs[1].gps_time - l.epochs[0].gps_time, 2.0);
        // With the option both take the same count: one second apart.
        let o = parse("b.nmea", &log, Some(17)).unwrap();
        assert_eq!(o.epochs[1].gps_time - o.epochs[0].gps_time, 1.0);
        // A date past the table: its last count, with a warning naming the line.
        let l = parse("f.nmea", &noon_log(1, 5, 2040), None).unwrap();
        assert_eq!(l.epochs[0].gps_time, gps_of(2040, 5, 1, 43_200.0, 18));
        assert_eq!(l.report.warnings.len(), 1);
        assert!(
            l.report.warnings[0].starts_with("f.nmea:2: date 2040-05-01 is past the leap-second"),
            "{:?}",
            l.report.warnings
        );
        let o = parse("f.nmea", &noon_log(1, 5, 2040), Some(19)).unwrap();
        assert!(o.report.warnings.is_empty());
        assert_eq!(o.epochs[0].gps_time, gps_of(2040, 5, 1, 43_200.0, 19));
    }

    #[test]
    fn two_sentences_on_a_line_and_any_line_ending() {
        let z = zda("120000.00", 23, 11, 2026);
        let g0 = gga("GN", "120000.00", "4912.0", "N", "01636.0", "E", 4);
        let g1 = gga("GN", "120000.10", "4912.0", "N", "01636.0", "E", 4);
        let hdt = with_checksum("GNHDT,45.000,T");
        // A lost line feed: ZDA and GGA on one line, GGA and HDT on the next; binary bytes
        // between two sentences.
        let joined = format!("{z}{g0}\r\n{g1}\u{1}\u{2}{hdt}\r\n");
        let l = parse("j.nmea", &joined, Some(18)).unwrap();
        assert_eq!(l.epochs.len(), 2, "{}", l.report);
        assert_eq!(l.report.used["ZDA"], 1);
        assert!(l.epochs[1].heading.is_some());
        assert_eq!((l.report.joined, l.report.stray_bytes), (2, 1));
        assert_eq!(l.report.skipped_bytes, 2);
        let text = l.report.to_string();
        assert!(
            text.contains("2 lines with more than one sentence"),
            "{text}"
        );
        // CR only, LF only, CR LF: the same epochs, the same lines.
        let lines3 = [z.as_str(), g0.as_str(), g1.as_str()];
        let want = parse("l.nmea", &lines3.join("\n"), Some(18)).unwrap();
        for sep in ["\r", "\r\n", "\n\r\n"] {
            let l = parse("l.nmea", &lines3.join(sep), Some(18)).unwrap();
            assert_eq!(l.epochs.len(), 2, "{sep:?}");
            assert_eq!(
                l.epochs.iter().map(|e| e.gps_time).collect::<Vec<_>>(),
                want.epochs.iter().map(|e| e.gps_time).collect::<Vec<_>>()
            );
            if sep != "\n\r\n" {
                assert_eq!(l.epochs[1].line, 3, "{sep:?}");
            }
        }
        // A checksum-bad sentence beside a good one: the bad one counted, the good one read.
        let mut bad = g1.clone();
        bad.replace_range(bad.len() - 2.., "00");
        let l = parse("b.nmea", &format!("{z}\n{bad}{g0}\n"), Some(18)).unwrap();
        assert_eq!((l.epochs.len(), l.report.corrupt), (1, 1), "{}", l.report);
        assert!(l.report.problems[0].starts_with("b.nmea:2: checksum 00"));
    }

    /// `(time, heading)` epochs of a receiver sending HDT before each GGA (Hemisphere) or
    /// after it, each epoch `[HDT] GGA RMC [HDT]`; headings 10, 20, 30... degrees.
    fn ordered_log(hdt_first: bool, epochs: usize) -> String {
        let rmc = |t: &str| {
            with_checksum(&format!(
                "GPRMC,{t},A,4912.0,N,01636.0,E,0.0,0.0,020226,,,D"
            ))
        };
        let mut out = Vec::new();
        for k in 0..epochs {
            let t = format!("1000{:02}.00", k);
            let hdt = with_checksum(&format!("HEHDT,{}.0,T", 10 * (k + 1)));
            if hdt_first {
                out.push(hdt.clone());
            }
            out.push(gga("GP", &t, "4912.0", "N", "01636.0", "E", 4));
            out.push(rmc(&t));
            if !hdt_first {
                out.push(hdt);
            }
        }
        out.join("\r\n")
    }

    #[test]
    fn hdt_order_is_detected_from_the_log() {
        for hdt_first in [true, false] {
            let l = parse("o.nmea", &ordered_log(hdt_first, 4), Some(18)).unwrap();
            let deg: Vec<f64> = l
                .epochs
                .iter()
                .map(|e| e.heading.map_or(-1.0, |h| h.to_degrees().round()))
                .collect();
            assert_eq!(deg, vec![10.0, 20.0, 30.0, 40.0], "first {hdt_first}");
            let note = l.report.notes.join(" ");
            let want = if hdt_first { "HDT first" } else { "HDT last" };
            assert!(note.contains(want), "{note}");
            assert_eq!(l.report.unusable, 0, "{}", l.report);
            assert_eq!(l.report.talkers["HE"], 4);
        }
        // Cut so that neither end tells: the order is said to be undecided.
        let log = ordered_log(true, 4);
        let cut: Vec<&str> = log.split("\r\n").collect();
        let l = parse("u.nmea", &cut[2..cut.len() - 1].join("\n"), Some(18)).unwrap();
        assert!(
            l.report.notes[0].contains("undecided"),
            "{:?}",
            l.report.notes
        );
        // HDT between sentences of its own epoch needs no detection.
        let l = parse("n.nmea", &noon_log(1, 2, 2026), Some(18)).unwrap();
        assert!(l.report.notes.is_empty());
    }

    /// A log read line by line as it grows ([`LogLines`]) gives what [`parse`] gives of it
    /// whole: HDT sent last, first (read again whole), undecided, none; corrupt lines;
    /// another name or leap seconds, or another text (read again whole). Its format is
    /// known from the lines when they are the text and none holds a UBX sync's first byte.
    #[test]
    fn log_read_as_it_grows_is_the_whole_logs() {
        let ordered = ordered_log(true, 4);
        let cut: Vec<&str> = ordered.split("\r\n").collect();
        let mut corrupt = noon_log(1, 2, 2026);
        corrupt.push_str("\n\u{1}\u{2}binary\nxx");
        corrupt.push_str(&gga("GP", "120000.10", "4912.0", "N", "01636.0", "E", 4));
        corrupt.push_str("\n\n$GPGGA,1*00");
        let logs = [
            ordered_log(false, 5),
            ordered.clone(),
            cut[2..cut.len() - 1].join("\n"),
            noon_log(1, 2, 2026),
            corrupt,
        ];
        for (k, log) in logs.iter().enumerate() {
            let mut grown = LogLines::new("g.nmea", Some(18));
            let mut text = String::new();
            for (_, raw) in lines(log) {
                grown.line(raw);
                text.push_str(raw);
                text.push_str("\r\n");
            }
            let whole = parse("g.nmea", &text, Some(18));
            assert_eq!(grown.format(text.as_bytes()), Some(Format::Nmea), "log {k}");
            let got = grown.finish("g.nmea", text.as_bytes(), Some(18));
            assert_eq!(format!("{:?}", got), format!("{:?}", whole), "log {k}");
        }
        let other = noon_log(1, 2, 2026);
        for (file, leap) in [("o.nmea", None), ("g.nmea", Some(18)), ("g.nmea", None)] {
            let mut grown = LogLines::new("g.nmea", None);
            grown.line(&gga("GP", "120000.10", "4912.0", "N", "01636.0", "E", 4));
            assert_eq!(grown.format(other.as_bytes()), None);
            assert_eq!(
                grown.finish(file, other.as_bytes(), leap).unwrap(),
                parse(file, &other, leap).unwrap()
            );
        }
    }

    /// A log of `epochs` 10 Hz epochs from 23:59:00 UTC on `day`.`month`.`year` (over
    /// midnight after 600), the first 5 before any date sentence, a ZDA every 10th epoch and
    /// an RMC after every other epoch's GGA; each epoch's GST comes `k % 19` epochs late and
    /// its HDT after its GGA; epoch 300 repeats 299's time and 400's time is in a leap second
    /// (23:59:60, skipped).
    fn long_log(epochs: usize, (day, month, year): (u32, u32, u32)) -> String {
        let time = |k: usize| {
            let t = 86_340.0 + 0.1 * k as f64;
            let t = if k == 300 { 86_340.0 + 29.9 } else { t };
            let s = t.rem_euclid(86_400.0);
            let (h, m) = ((s / 3600.0) as u32, (s % 3600.0 / 60.0) as u32);
            let sec = if k == 400 { 60.05 } else { s % 60.0 };
            format!("{h:02}{m:02}{sec:05.2}")
        };
        let date = |k: usize| {
            if 86_340.0 + 0.1 * k as f64 >= 86_400.0 {
                day + 1
            } else {
                day
            }
        };
        let mut out = Vec::new();
        let mut late: Vec<(usize, String)> = Vec::new();
        for k in 0..epochs {
            let t = time(k);
            if k >= 5 && k % 10 == 0 {
                out.push(zda(&t, date(k), month, year));
            }
            out.push(gga("GN", &t, "4912.0", "N", "01636.0", "E", 4));
            out.push(with_checksum(&format!("GNHDT,{}.0,T", k % 360)));
            if k >= 5 && k % 2 == 1 {
                out.push(with_checksum(&format!(
                    "GNRMC,{t},A,4912.0,N,01636.0,E,0.0,0.0,{:02}{month:02}{:02},,,D",
                    date(k),
                    year % 100
                )));
            }
            let gst = format!("GNGST,{t},0.5,0.02,0.01,30.0,0.0{},0.012,0.03", k % 10);
            late.push((k + k % 19, with_checksum(&gst)));
            late.retain(|(at, g)| {
                let due = *at <= k;
                if due {
                    out.push(g.clone());
                }
                !due
            });
        }
        out.join("\r\n")
    }

    /// A long log read as it grows ([`LogLines`], which dates its settled epochs as they
    /// come) gives what [`parse`] gives of it whole: over midnight, with epochs before the
    /// first date, late GSTs, a repeated epoch, a leap second, a date past the leap-second
    /// table (its warning), with and without `--leap-seconds`.
    #[test]
    fn a_long_log_dated_as_it_grows_is_the_whole_log() {
        for (date, leap) in [
            ((27, 2, 2026), Some(18)),
            ((27, 2, 2026), None),
            ((29, 6, 2079), None),
        ] {
            let log = long_log(700, date);
            let mut grown = LogLines::new("g.nmea", leap);
            let mut text = String::new();
            for (_, raw) in lines(&log) {
                grown.line(raw);
                text.push_str(raw);
                text.push_str("\r\n");
            }
            assert!(
                grown.reader.dating.done > 400,
                "{date:?}: settled epochs dated as read"
            );
            let whole = parse("g.nmea", &text, leap).unwrap();
            assert_eq!(whole.report.corrupt, 0, "{date:?}: {}", whole.report);
            assert!(whole.report.unusable >= 2, "{date:?}: {}", whole.report);
            assert!(whole
                .report
                .problems
                .iter()
                .any(|p| p.contains("not after")));
            assert_eq!(whole.report.warnings.len(), usize::from(date.2 == 2079));
            let with_gst = whole
                .epochs
                .iter()
                .filter(|e| e.sigma_north_east_up.is_some())
                .count();
            assert!(
                with_gst > 600,
                "{date:?}: {with_gst} of {}: {}",
                whole.epochs.len(),
                whole.report
            );
            let got = grown.finish("g.nmea", text.as_bytes(), leap).unwrap();
            assert_eq!(format!("{got:?}"), format!("{whole:?}"), "{date:?}");
        }
    }

    /// The format of the lines given is [`super::detect_format`]'s of their text, or unknown
    /// where a line holds 0xB5 (a UBX sync's first byte, here inside a UTF-8 'µ').
    #[test]
    fn log_lines_know_their_format() {
        let formats = [
            ("x,y\r\n1,2\r\n", Some(Format::Csv)),
            ("% program : RTKPOST\r\n", Some(Format::Rtklib)),
            ("\r\n# c\r\n$GPZDA,1*00\r\n", Some(Format::Nmea)),
            ("$GPTXT,µ*00\r\n", None),
        ];
        for (text, format) in formats {
            let mut grown = LogLines::new("f", None);
            for raw in text.split_terminator("\r\n") {
                grown.line(raw);
            }
            assert_eq!(grown.format(text.as_bytes()), format, "{text:?}");
            if let Some(f) = format {
                assert_eq!(f, super::super::detect_format(text.as_bytes(), text));
            }
            assert_eq!(grown.format(&text.as_bytes()[1..]), None, "{text:?}");
        }
    }

    #[test]
    fn published_sentences_joined_and_with_carriage_returns_only() {
        // The Trimble GGA and GST of `published_receiver_sentences`, written as a receiver
        // that lost a line feed and ends lines with CR only.
        let zda = zda("172813.00", 12, 7, 2024);
        let gga = "$GPGGA,172814.0,3723.46587704,N,12202.26957864,W,2,6,1.2,18.893,M,-25.669,M,2.0,0031*4F";
        let gst = "$GPGST,172814.0,0.006,0.023,0.020,273.6,0.023,0.020,0.031*6A";
        let log = format!("{zda}\r{gga}{gst}\r");
        let l = parse("t.nmea", &log, Some(18)).unwrap();
        assert_eq!(l.epochs.len(), 1, "{}", l.report);
        let e = &l.epochs[0];
        assert_eq!(e.line, 2);
        assert!(e.sigma_north_east_up.is_some(), "{}", l.report);
        assert_eq!((l.report.joined, l.report.corrupt), (1, 0));
        assert_eq!(l.report.talkers["GP"], 3);
    }
}
