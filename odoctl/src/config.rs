//! Chassis parameters by their shared key names: TOML files, `--set KEY=VALUE`, and the
//! calibration result file.
//!
//! A parameter TOML holds any of the shared keys at top level (missing keys keep the designed
//! values of Tables 2-3, `ChassisParams::DESIGNED`); a `[fit]` table (written by `calibrate`)
//! is ignored when reading. Unknown keys, wrong types and values that fail
//! `ChassisParams::validate` are errors naming the file and line.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};

use odo_core::odometry::{ChassisParams, UncertaintyModel};

/// Every shared key, in the order files list them.
pub const KEYS: &[&str] = &[
    "left_diameter",
    "right_diameter",
    "track_width",
    "ticks_per_rev",
    "delta_left",
    "delta_right",
    "delta_diff",
    "uncertainty_model",
    "kappa_left",
    "kappa_right",
    "left_cos1",
    "left_cos2",
    "left_cos3",
    "left_sin1",
    "left_sin2",
    "left_sin3",
    "right_cos1",
    "right_cos2",
    "right_cos3",
    "right_sin1",
    "right_sin2",
    "right_sin3",
];

/// The keys every calibration file carries (issue 5); the others are written when they differ
/// from the designed values.
pub const MAIN_KEYS: &[&str] = &[
    "left_diameter",
    "right_diameter",
    "track_width",
    "ticks_per_rev",
    "delta_left",
    "delta_right",
];

/// A key's value as text (as files and the unit print it).
pub fn get_key(p: &ChassisParams, key: &str) -> Result<String> {
    Ok(match key {
        "left_diameter" => fmt_f64(p.left_diameter),
        "right_diameter" => fmt_f64(p.right_diameter),
        "track_width" => fmt_f64(p.track_width),
        "ticks_per_rev" => p.ticks_per_rev.to_string(),
        "delta_left" => fmt_f32(p.delta_left),
        "delta_right" => fmt_f32(p.delta_right),
        "delta_diff" => fmt_f32(p.delta_diff),
        "uncertainty_model" => model_name(p.uncertainty_model).to_string(),
        "kappa_left" => fmt_f32(p.kappa_left),
        "kappa_right" => fmt_f32(p.kappa_right),
        _ => match read_harmonic(p, key) {
            Some(v) => fmt_f32(v),
            None => bail!("unknown key `{key}` (keys: {})", KEYS.join(", ")),
        },
    })
}

fn read_harmonic(p: &ChassisParams, key: &str) -> Option<f32> {
    let (wheel, rest) = match key.split_once('_')? {
        ("left", r) => (&p.left_wheel, r),
        ("right", r) => (&p.right_wheel, r),
        _ => return None,
    };
    let (arr, n) = if let Some(n) = rest.strip_prefix("cos") {
        (&wheel.cos, n)
    } else {
        (&wheel.sin, rest.strip_prefix("sin")?)
    };
    let i: usize = n.parse().ok()?;
    arr.get(i.checked_sub(1)?).copied()
}

fn write_harmonic(p: &mut ChassisParams, key: &str, v: f32) -> bool {
    let (wheel, rest) = match key.split_once('_') {
        Some(("left", r)) => (&mut p.left_wheel, r),
        Some(("right", r)) => (&mut p.right_wheel, r),
        _ => return false,
    };
    let (arr, n) = if let Some(n) = rest.strip_prefix("cos") {
        (&mut wheel.cos, n)
    } else if let Some(n) = rest.strip_prefix("sin") {
        (&mut wheel.sin, n)
    } else {
        return false;
    };
    match n
        .parse::<usize>()
        .ok()
        .and_then(|i| i.checked_sub(1))
        .and_then(|i| arr.get_mut(i))
    {
        Some(slot) => {
            *slot = v;
            true
        }
        None => false,
    }
}

/// The name of an uncertainty model as the key `uncertainty_model` spells it.
pub fn model_name(m: UncertaintyModel) -> &'static str {
    match m {
        UncertaintyModel::Paper => "paper",
        UncertaintyModel::Covariance => "covariance",
    }
}

fn parse_model(v: &str) -> Result<UncertaintyModel> {
    match v {
        "paper" => Ok(UncertaintyModel::Paper),
        "covariance" => Ok(UncertaintyModel::Covariance),
        _ => bail!("`{v}` is not an uncertainty model (paper, covariance)"),
    }
}

/// Shortest text that reads back as the same f64, always with a decimal point or exponent.
pub fn fmt_f64(v: f64) -> String {
    format!("{v:?}")
}

/// Shortest text that reads back as the same f32, always with a decimal point or exponent.
pub fn fmt_f32(v: f32) -> String {
    format!("{v:?}")
}

/// Sets one key from its text value; the result is not validated (see [`validated`]).
pub fn set_key(p: &mut ChassisParams, key: &str, value: &str) -> Result<()> {
    let value = value.trim();
    let num = || -> Result<f64> {
        let v: f64 = value
            .parse()
            .map_err(|_| anyhow!("{key}: `{value}` is not a number"))?;
        if !v.is_finite() {
            bail!("{key}: `{value}` is not a finite number");
        }
        Ok(v)
    };
    match key {
        "left_diameter" => p.left_diameter = num()?,
        "right_diameter" => p.right_diameter = num()?,
        "track_width" => p.track_width = num()?,
        "ticks_per_rev" => {
            p.ticks_per_rev = value
                .parse()
                .map_err(|_| anyhow!("{key}: `{value}` is not a positive integer"))?
        }
        "delta_left" => p.delta_left = num()? as f32,
        "delta_right" => p.delta_right = num()? as f32,
        "delta_diff" => p.delta_diff = num()? as f32,
        "uncertainty_model" => p.uncertainty_model = parse_model(value.trim_matches('"'))?,
        "kappa_left" => p.kappa_left = num()? as f32,
        "kappa_right" => p.kappa_right = num()? as f32,
        _ => {
            if read_harmonic(p, key).is_none() {
                bail!("unknown key `{key}` (keys: {})", KEYS.join(", "));
            }
            write_harmonic(p, key, num()? as f32);
        }
    }
    Ok(())
}

/// Applies `KEY=VALUE` assignments (from `--set`).
pub fn apply_sets(p: &mut ChassisParams, sets: &[String]) -> Result<()> {
    for s in sets {
        let (k, v) = s
            .split_once('=')
            .ok_or_else(|| anyhow!("--set {s}: expected KEY=VALUE"))?;
        set_key(p, k.trim(), v).with_context(|| format!("--set {s}"))?;
    }
    Ok(())
}

/// Checks parameters, naming the offending key and where they came from.
pub fn validated(p: ChassisParams, origin: &str) -> Result<ChassisParams> {
    p.validate().map_err(|e| anyhow!("{origin}: {e}"))?;
    Ok(p)
}

fn line_of(text: &str, key: &str) -> usize {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.strip_prefix(key)
                .is_some_and(|r| r.trim_start().starts_with('='))
        })
        .map_or(1, |i| i + 1)
}

/// Parses a parameter TOML text over `base`; `file` names it in errors.
pub fn parse_params(file: &str, text: &str, base: ChassisParams) -> Result<ChassisParams> {
    let table: toml::Table =
        toml::from_str(text).map_err(|e| anyhow!("{file}: {}", e.to_string().trim_end()))?;
    let mut p = base;
    for (key, value) in &table {
        let line = line_of(text, key);
        let text_value = match value {
            toml::Value::Table(_) if key == "fit" => continue,
            toml::Value::Float(f) => fmt_f64(*f),
            toml::Value::Integer(i) => i.to_string(),
            toml::Value::String(s) => s.clone(),
            _ => bail!("{file}:{line}: `{key}` must be a number or a string"),
        };
        if !KEYS.contains(&key.as_str()) {
            bail!(
                "{file}:{line}: unknown key `{key}` (keys: {})",
                KEYS.join(", ")
            );
        }
        set_key(&mut p, key, &text_value).map_err(|e| anyhow!("{file}:{line}: {e}"))?;
        if let Err(e) = check_one(&p, key) {
            bail!("{file}:{line}: {e}");
        }
    }
    validated(p, file)
}

fn check_one(p: &ChassisParams, key: &str) -> Result<()> {
    match p.validate() {
        Err(e) if e.to_string().starts_with(key) => Err(anyhow!("{e}")),
        _ => Ok(()),
    }
}

/// Reads a parameter TOML file over `base`.
pub fn read_params(path: &Path, base: ChassisParams) -> Result<ChassisParams> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    parse_params(&path.display().to_string(), &text, base)
}

/// Parameters from an optional TOML file and `--set` assignments, over the designed values.
pub fn load(config: Option<&Path>, sets: &[String]) -> Result<ChassisParams> {
    let mut p = match config {
        Some(path) => read_params(path, ChassisParams::DESIGNED)?,
        None => ChassisParams::DESIGNED,
    };
    apply_sets(&mut p, sets)?;
    validated(p, "--set")
}

/// The keys a parameter file lists: the main keys, and any other key whose value differs from
/// the designed one.
pub fn keys_to_write(p: &ChassisParams) -> Vec<&'static str> {
    let d = ChassisParams::DESIGNED;
    KEYS.iter()
        .copied()
        .filter(|k| MAIN_KEYS.contains(k) || get_key(p, k).ok() != get_key(&d, k).ok())
        .collect()
}

/// A value of the `[fit]` table.
#[derive(Debug, Clone)]
pub enum FitValue {
    /// A number.
    Num(f64),
    /// An integer.
    Int(i64),
    /// A string.
    Text(String),
}

/// Renders a parameter file: a comment header, the shared keys at top level, then `[fit]`.
pub fn render_params(p: &ChassisParams, comment: &str, fit: &[(&str, FitValue)]) -> String {
    render_params_with(p, comment, fit, &[])
}

/// [`render_params`] that also writes the keys `always` (e.g. a fitted `delta_diff` of 0).
pub fn render_params_with(
    p: &ChassisParams,
    comment: &str,
    fit: &[(&str, FitValue)],
    always: &[&str],
) -> String {
    let mut s = String::new();
    for line in comment.lines() {
        let _ = writeln!(s, "# {line}");
    }
    let listed = keys_to_write(p);
    for k in KEYS
        .iter()
        .copied()
        .filter(|k| listed.contains(k) || always.contains(k))
    {
        let v = get_key(p, k).expect("known key");
        if k == "uncertainty_model" {
            let _ = writeln!(s, "{k} = \"{v}\"");
        } else {
            let _ = writeln!(s, "{k} = {v}");
        }
    }
    if !fit.is_empty() {
        s.push_str("\n[fit]\n");
        for (k, v) in fit {
            let _ = match v {
                FitValue::Num(x) if x.is_finite() => writeln!(s, "{k} = {x:?}"),
                FitValue::Num(x) => writeln!(
                    s,
                    "{k} = {}",
                    if x.is_nan() {
                        "nan"
                    } else if *x > 0.0 {
                        "inf"
                    } else {
                        "-inf"
                    }
                ),
                FitValue::Int(i) => writeln!(s, "{k} = {i}"),
                FitValue::Text(t) => writeln!(s, "{k} = {}", toml::Value::String(t.clone())),
            };
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_roundtrips() {
        let mut p = ChassisParams::DESIGNED;
        for (i, k) in KEYS.iter().enumerate() {
            let v = match *k {
                "ticks_per_rev" => "4096".to_string(),
                "uncertainty_model" => "covariance".to_string(),
                "left_diameter" | "right_diameter" | "track_width" => format!("0.{}", 250 + i),
                _ => format!("{}e-4", i + 1),
            };
            set_key(&mut p, k, &v).unwrap();
        }
        p.validate().unwrap();
        let text = render_params(&p, "test", &[("initial_heading", FitValue::Num(0.5))]);
        let back = parse_params("x.toml", &text, ChassisParams::DESIGNED).unwrap();
        assert_eq!(back, p);
        assert_eq!(get_key(&back, "right_sin3").unwrap(), "0.0022");
    }

    #[test]
    fn errors_name_file_line_and_key() {
        let e = parse_params(
            "c.toml",
            "left_diameter = 0.26\nfoo = 1\n",
            ChassisParams::DESIGNED,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("c.toml:2") && e.to_string().contains("foo"),
            "{e}"
        );
        let e =
            parse_params("c.toml", "track_width = 99.0\n", ChassisParams::DESIGNED).unwrap_err();
        assert!(
            e.to_string().contains("c.toml:1") && e.to_string().contains("track_width"),
            "{e}"
        );
        let e = parse_params("c.toml", "track_width = \n", ChassisParams::DESIGNED).unwrap_err();
        assert!(e.to_string().contains("c.toml"), "{e}");
        let e =
            parse_params("c.toml", "ticks_per_rev = 1.5\n", ChassisParams::DESIGNED).unwrap_err();
        assert!(e.to_string().contains("ticks_per_rev"), "{e}");
        let mut p = ChassisParams::DESIGNED;
        assert!(apply_sets(&mut p, &["left_cos4=0.1".into()]).is_err());
        assert!(apply_sets(&mut p, &["left_diameter".into()]).is_err());
        apply_sets(&mut p, &["left_diameter=0.3".into()]).unwrap();
        assert_eq!(p.left_diameter, 0.3);
    }
}
