//! `odoctl reference FILE`: what a user checks in a reference before a calibration drive is
//! trusted (receiver and talkers, time span and rate, epochs by fix quality over time, gaps,
//! reported sigmas, origin, heading source, what was skipped and why), or with `--to` its
//! used epochs as CSV, TUM, GeoJSON or GPX.

use std::io::Write;
use std::process::ExitCode;

use anyhow::{Context, Result};

use super::{create, reference_options};
use crate::cli::ReferenceCmdArgs;
use crate::reference::summary::{self, Inspection, Summary};
use crate::reference::{gps_time, FixQuality, Format, TimeScale};

/// Runs `odoctl reference`.
pub fn run(a: &ReferenceCmdArgs) -> Result<ExitCode> {
    let o = reference_options(&a.input)?;
    let file = a.file.display().to_string();
    let bytes = std::fs::read(&a.file).with_context(|| format!("{file}: cannot read"))?;
    let insp = summary::inspect(&file, &bytes, &o)?;
    if let Some(format) = a.to {
        match &a.output {
            Some(p) => {
                let mut w = create(p)?;
                summary::export(&mut w, &insp.reference, format, o.leap_seconds)?;
                w.flush()
                    .with_context(|| format!("{}: cannot write", p.display()))?;
                eprintln!(
                    "{}: {} epochs to {}",
                    file,
                    insp.reference.epochs.len(),
                    p.display()
                );
            }
            None => {
                let mut w = std::io::BufWriter::new(std::io::stdout().lock());
                summary::export(&mut w, &insp.reference, format, o.leap_seconds)?;
                // A closed pipe ends the output quietly.
                let _ = w.flush();
            }
        }
        return Ok(ExitCode::SUCCESS);
    }
    print_summary(&file, &insp);
    Ok(ExitCode::SUCCESS)
}

/// The maker whose proprietary NMEA sentences start with `talker` (`P` + three letters).
fn maker(talker: &str) -> Option<&'static str> {
    Some(match talker {
        "PUBX" => "u-blox (PUBX)",
        "PTNL" => "Trimble (PTNL)",
        "PSAT" => "Hemisphere (PSAT)",
        "PASH" => "Ashtech format (PASH)",
        "PSTI" => "SkyTraq (PSTI)",
        "PMTK" => "MediaTek (PMTK)",
        "PQTM" => "Quectel (PQTM)",
        "PGRM" => "Garmin (PGRM)",
        "PSRF" => "SiRF (PSRF)",
        "PAIR" => "Airoha (PAIR)",
        _ => return None,
    })
}

/// A time for the summary: GPS week/TOW and UTC for a receiver log, seconds for a CSV.
fn when(insp: &Inspection, t: f64) -> String {
    match insp.reference.time {
        TimeScale::Gps => gps_time::describe(t, gps_time::leap_seconds_at_gps(t)),
        TimeScale::Samples | TimeScale::Trajectory => format!("t = {t:.3} s"),
    }
}

fn print_summary(file: &str, insp: &Inspection) {
    let s = summary::summarize(&insp.points());
    outln!("{file}: {}", insp.format);
    if let Some(log) = &insp.log {
        let r = &log.report;
        if let Some(rx) = &r.receiver {
            outln!("receiver: {rx}");
        }
        let makers: Vec<&str> = r.talkers.keys().filter_map(|t| maker(t)).collect();
        if !makers.is_empty() {
            outln!(
                "receiver, by its proprietary sentences: {}",
                makers.join(", ")
            );
        }
        if !r.talkers.is_empty() {
            let t: Vec<String> = r
                .talkers
                .iter()
                .map(|(k, n)| format!("{k} ({n})"))
                .collect();
            outln!("talkers: {}", t.join(", "));
        }
    }
    print_time(insp, &s);
    print_fix_table(&s);
    print_sigmas(&s);
    let r = &insp.reference;
    match r.origin {
        Some(g) => outln!(
            "origin: {:.9} {:.9} {:.4} m ({})",
            g.lat_deg,
            g.lon_deg,
            g.height,
            match r.origin_epochs {
                0 => "given".to_string(),
                1 => "the first used epoch".to_string(),
                n => format!("mean of the {n} epochs of the opening standstill"),
            }
        ),
        None => outln!("origin: the {}'s own local frame", r.format),
    }
    outln!("heading: {}", heading_source(insp, &s));
    outln!("use: {}", r.report);
}

fn print_time(insp: &Inspection, s: &Summary) {
    if s.epochs == 0 {
        return;
    }
    outln!(
        "time: {} .. {} ({:.1} s, {} epochs)",
        when(insp, s.span.0),
        when(insp, s.span.1),
        s.span.1 - s.span.0,
        s.epochs
    );
    if s.interval.is_finite() && s.interval > 0.0 {
        outln!(
            "rate: {:.3} Hz (median interval {:.3} s)",
            1.0 / s.interval,
            s.interval
        );
    }
    outln!(
        "gaps longer than twice the median interval: {}",
        s.gaps.len()
    );
    for (t, d) in s.gaps.iter().take(10) {
        outln!("  {:.3} s after {}", d, when(insp, *t));
    }
    if s.gaps.len() > 10 {
        outln!("  ... {} more", s.gaps.len() - 10);
    }
}

fn print_fix_table(s: &Summary) {
    let all = [
        FixQuality::RtkFixed,
        FixQuality::RtkFloat,
        FixQuality::Ppp,
        FixQuality::Dgps,
        FixQuality::Sbas,
        FixQuality::Single,
        FixQuality::Invalid,
    ];
    let seen: Vec<FixQuality> = all
        .into_iter()
        .filter(|q| s.buckets.iter().any(|b| b.counts.contains_key(q)))
        .collect();
    outln!(
        "epochs by fix quality, per {:.0} s from the first:",
        s.bucket
    );
    let head: Vec<String> = seen
        .iter()
        .map(|q| format!("{:>14}", q.to_string()))
        .collect();
    outln!("  {:>8}{}", "from s", head.join(""));
    for b in &s.buckets {
        let row: Vec<String> = seen
            .iter()
            .map(|q| format!("{:>14}", b.counts.get(q).copied().unwrap_or(0)))
            .collect();
        outln!("  {:>8.0}{}", b.start, row.join(""));
    }
}

fn print_sigmas(s: &Summary) {
    let line = |name: &str, v: Option<(f64, f64, usize)>| match v {
        Some((m, p, n)) => outln!(
            "{name} sigma reported: median {:.4} m, 95 % {:.4} m ({n} epochs)",
            m,
            p
        ),
        None => outln!("{name} sigma: not reported"),
    };
    line("horizontal", s.sigma_h);
    line("vertical", s.sigma_up);
}

fn heading_source(insp: &Inspection, s: &Summary) -> String {
    let source = match insp.format {
        Format::Nmea => "NMEA HDT",
        Format::Ubx => "UBX NAV-RELPOSNED (moving base)",
        Format::Csv => "the CSV's heading column",
        Format::Rtklib => "none (RTKLIB .pos has no heading)",
        Format::Tum | Format::Mcap => "the trajectory's orientation (yaw of its quaternion)",
    };
    if s.headings == 0 {
        "none".to_string()
    } else {
        format!(
            "{source} on {} of {} epochs (the order and what was not used: below)",
            s.headings, s.epochs
        )
    }
}
