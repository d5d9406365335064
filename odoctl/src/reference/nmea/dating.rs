//! The dating of an NMEA log's GGA epochs (the parent module's doc): each by the nearest
//! earlier date, in GPS time.

use anyhow::Result;

use super::super::geodetic::Geodetic;
use super::super::{gps_time, Epoch, FixQuality, ReadReport};
use crate::cancel::check_this_thread;

/// A GGA before dating.
#[derive(Clone)]
pub(super) struct Undated {
    pub(super) sod: f64,
    pub(super) position: Geodetic,
    pub(super) fix: FixQuality,
    pub(super) heading: Option<f64>,
    /// Standard deviations north, east, up (m), from the GST of the same time.
    pub(super) sigma_north_east_up: Option<[f64; 3]>,
    pub(super) line: usize,
    /// The last date sentence before it (index into the dates).
    pub(super) date: Option<usize>,
}

/// A date sentence: (days since 1970-01-01, seconds of the day, line).
#[derive(Clone, Copy)]
pub(super) struct DateMark {
    pub(super) days: i64,
    pub(super) sod: f64,
    pub(super) line: usize,
}

/// Epochs dated (or converted) between two checks of the thread's cancel flag.
pub(crate) const CANCEL_CHECK_EPOCHS: usize = 4096;

/// The dating of a log's GGA epochs as far as it has gone (see the module doc): converts to
/// GPS time and drops epochs before the GPS epoch and epochs whose time is not after the
/// previous one's (a repeat of the same time gives the epoch kept the HDT or GST that went
/// with it), counting them. Its problems and its warning join the log's report at the end
/// ([`Dating::finish`]), after the reading's, as when the log is dated whole.
#[derive(Clone, Default)]
pub(super) struct Dating {
    /// Epochs dated (dropped ones included).
    pub(super) done: usize,
    /// The date of the last epoch kept or dropped after its conversion.
    prev: Option<DateMark>,
    /// The epochs kept.
    pub(super) epochs: Vec<Epoch>,
    /// Its unusable epochs and their first messages.
    report: ReadReport,
    /// The first epoch's warning of a date past the leap-second table.
    warning: Option<String>,
}

impl Dating {
    /// Dates `undated[self.done..]` by `dates` with `leap_seconds` (the log's: the same at
    /// every call).
    /// Checks the thread's cancel flag every [`CANCEL_CHECK_EPOCHS`] epochs, before dating
    /// the next one: an error leaves the rest to date.
    pub(super) fn date(
        &mut self,
        file: &str,
        undated: &[Undated],
        dates: &[DateMark],
        leap_seconds: Option<i32>,
    ) -> Result<()> {
        let Some(&first_date) = dates.first() else {
            return Ok(());
        };
        self.epochs.reserve(undated.len().saturating_sub(self.done));
        for (n, u) in undated.iter().enumerate().skip(self.done) {
            if n % CANCEL_CHECK_EPOCHS == 0 {
                check_this_thread()?;
            }
            self.done = n + 1;
            let mark = match (u.date.map(|k| dates[k]), self.prev) {
                (Some(d), Some(p)) => {
                    if d.line > p.line {
                        d
                    } else {
                        p
                    }
                }
                (Some(d), None) => d,
                (None, Some(p)) => p,
                (None, None) => first_date,
            };
            let mut days = mark.days;
            if u.sod - mark.sod > 43_200.0 {
                days -= 1;
            } else if mark.sod - u.sod > 43_200.0 {
                days += 1;
            }
            if self.warning.is_none() {
                let at = format_args!("{file}:{}", u.line);
                self.warning = gps_time::leap_table_warning(at, days, leap_seconds);
            }
            let leap = gps_time::leap_seconds_for(days, leap_seconds);
            let gps_time = match gps_time::utc_to_gps(days, u.sod, leap) {
                Ok(t) => t,
                Err(e) => {
                    self.report
                        .unusable(format!("{file}:{}: GGA: {e}: skipped", u.line));
                    continue;
                }
            };
            self.prev = Some(DateMark {
                days,
                sod: u.sod,
                line: u.line,
            });
            if let Some(last) = self.epochs.last_mut() {
                if gps_time <= last.gps_time {
                    self.report.unusable(format!(
                        "{file}:{}: GGA time is not after the previous epoch's (line {}): skipped",
                        u.line, last.line
                    ));
                    // A repeated GGA of the same epoch may have taken its HDT or GST.
                    if gps_time == last.gps_time {
                        last.heading = last.heading.or(u.heading);
                        last.sigma_north_east_up =
                            last.sigma_north_east_up.or(u.sigma_north_east_up);
                    }
                    continue;
                }
            }
            self.epochs.push(Epoch {
                gps_time,
                position: u.position,
                heading: u.heading,
                sigma_north_east_up: u.sigma_north_east_up,
                fix: u.fix,
                line: u.line,
            });
        }
        Ok(())
    }

    /// The epochs dated, their unusable ones counted into `report` and their first problems
    /// and the leap-table warning (when the reading warned of nothing) added after its own.
    pub(super) fn finish(self, report: &mut ReadReport) -> Vec<Epoch> {
        report.unusable += self.report.unusable;
        for p in self.report.problems {
            report.problem(p);
        }
        if report.warnings.is_empty() {
            report.warnings.extend(self.warning);
        }
        self.epochs
    }
}
