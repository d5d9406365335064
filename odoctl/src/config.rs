//! Settings by their shared key names, all from the core's key table
//! (`odo_unit::settings::keys`): parameter TOML files, `--set KEY=VALUE`, the calibration
//! result file, and the `set` lines of `odoctl config push`.
//!
//! Values are parsed by the unit's own parser ([`odo_unit::settings::parse_value`]: f32
//! keys correctly rounded straight from the decimal text, never through f64) and written in
//! the unit's text form, so a value goes from a file to the unit bit for bit. A parameter
//! TOML holds any of the chassis keys at top level (missing keys keep the designed values of
//! Tables 2-3, `ChassisParams::DESIGNED`); a `[fit]` table (written by `calibrate`) is
//! ignored when reading. A unit configuration for `config push` may hold every key. Unknown
//! keys, wrong types and values the unit would refuse are errors naming the file and line
//! ([`ConfigError`]).

use std::fmt::{self, Write as _};
use std::path::Path;

use anyhow::{Context, Result};
use odo_unit::settings::{
    validate_chassis, Choice, Group, Key, SettingError, Settings, RELATED_KEYS,
};

use odo_unit::odometry::{ChassisParams, UncertaintyModel};

/// Why a file, an assignment or a value was refused. `origin` names the file (or `--set`).
#[derive(Debug, Clone, PartialEq)]
pub enum ConfigError {
    /// The text is not TOML (the parser's message).
    Toml {
        /// File.
        origin: String,
        /// The TOML parser's message.
        message: String,
    },
    /// No key of that name.
    UnknownKey {
        /// File or `--set`.
        origin: String,
        /// Line, 1-based (0: not from a file).
        line: usize,
        /// The name given.
        key: String,
    },
    /// A unit option (`rate`, `mode`, ...) where only chassis parameters belong.
    NotChassis {
        /// File or `--set`.
        origin: String,
        /// Line, 1-based (0: not from a file).
        line: usize,
        /// The key.
        key: Key,
    },
    /// A TOML value that is neither a number nor a string (table, array, boolean, date).
    NotAValue {
        /// File.
        origin: String,
        /// Line, 1-based.
        line: usize,
        /// The key.
        key: Key,
    },
    /// A value refused by the key table or chassis relations, as the unit would refuse it.
    Setting {
        /// File or `--set`.
        origin: String,
        /// Line of the key the error names, 1-based (0: not from a file, or no such line).
        line: usize,
        /// The unit's error.
        error: SettingError,
    },
    /// A `--set` argument without `=`.
    NotAnAssignment(String),
    /// A file for `config push` without any key.
    NothingToSend(String),
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let at = |f: &mut fmt::Formatter<'_>, origin: &str, line: usize| {
            if line > 0 {
                write!(f, "{origin}:{line}: ")
            } else {
                write!(f, "{origin}: ")
            }
        };
        match self {
            Self::Toml { origin, message } => write!(f, "{origin}: {message}"),
            Self::UnknownKey { origin, line, key } => {
                at(f, origin, *line)?;
                write!(f, "unknown key `{}` (keys: ", crate::text::excerpt(key))?;
                for (i, k) in Key::ALL.iter().enumerate() {
                    write!(f, "{}{}", if i == 0 { "" } else { ", " }, k.name())?;
                }
                f.write_str(")")
            }
            Self::NotChassis { origin, line, key } => {
                at(f, origin, *line)?;
                write!(
                    f,
                    "`{}` is a unit option, not a chassis parameter (send it with `odoctl config push`)",
                    key.name()
                )
            }
            Self::NotAValue { origin, line, key } => {
                at(f, origin, *line)?;
                write!(f, "`{}` must be a number or a string", key.name())
            }
            Self::Setting {
                origin,
                line,
                error,
            } => {
                at(f, origin, *line)?;
                write!(f, "{error}")
            }
            Self::NotAnAssignment(s) => write!(f, "--set {s}: expected KEY=VALUE"),
            Self::NothingToSend(origin) => write!(f, "{origin}: no parameter keys to send"),
        }
    }
}

impl std::error::Error for ConfigError {}

/// The chassis keys, in the order files list them.
pub fn chassis_keys() -> impl Iterator<Item = Key> {
    Key::ALL
        .into_iter()
        .filter(|k| k.info().group == Group::Chassis)
}

/// The keys every calibration file carries; the others are written when they differ
/// from the designed values.
pub const MAIN_KEYS: [Key; 6] = [
    Key::LeftDiameter,
    Key::RightDiameter,
    Key::TrackWidth,
    Key::TicksPerRev,
    Key::DeltaLeft,
    Key::DeltaRight,
];

fn with_chassis(p: &ChassisParams) -> Settings {
    Settings {
        chassis: *p,
        ..Settings::DEFAULT
    }
}

/// A key's value in the unit's text form (as `get` prints it).
pub fn value_text(s: &Settings, key: Key) -> String {
    s.get(key).to_string()
}

/// A chassis key's value in the unit's text form.
pub fn chassis_value_text(p: &ChassisParams, key: Key) -> String {
    value_text(&with_chassis(p), key)
}

/// The name of an uncertainty model as the key `uncertainty_model` spells it.
pub fn model_name(m: UncertaintyModel) -> &'static str {
    m.word()
}

/// Applies `KEY=VALUE` assignments (from `--set`) to chassis parameters; each value is
/// parsed and range-checked as the unit does (relations: [`validated`]).
pub fn apply_sets(p: &mut ChassisParams, sets: &[String]) -> Result<()> {
    let mut s = with_chassis(p);
    for a in sets {
        let (k, v) = a
            .split_once('=')
            .ok_or_else(|| ConfigError::NotAnAssignment(a.clone()))?;
        let origin = format!("--set {a}");
        let key = chassis_key(&origin, 0, k.trim())?;
        s.set(key, v.trim()).map_err(|error| ConfigError::Setting {
            origin,
            line: 0,
            error,
        })?;
    }
    *p = s.chassis;
    Ok(())
}

/// The chassis key of a name, or why it is none.
fn chassis_key(origin: &str, line: usize, name: &str) -> Result<Key, ConfigError> {
    let key = Key::from_name(name).ok_or_else(|| ConfigError::UnknownKey {
        origin: origin.into(),
        line,
        key: name.into(),
    })?;
    if key.info().group != Group::Chassis {
        return Err(ConfigError::NotChassis {
            origin: origin.into(),
            line,
            key,
        });
    }
    Ok(key)
}

/// Checks chassis parameters as the unit does (each key's range, then their relations),
/// naming the offending key and where they came from.
pub fn validated(p: ChassisParams, origin: &str) -> Result<ChassisParams> {
    validate_chassis(&p).map_err(|error| ConfigError::Setting {
        origin: origin.into(),
        line: 0,
        error,
    })?;
    Ok(p)
}

/// One top-level entry of a TOML file: the key, its line and the value's text.
struct Entry {
    key: Key,
    line: usize,
    text: String,
}

/// Reads the top-level keys of a TOML text in file order, with the text of each value as
/// the unit would read it: a number exactly as written (TOML's digit separators `_`
/// removed; never through a float of the TOML parser), a string's content.
fn entries(origin: &str, text: &str) -> Result<Vec<Entry>, ConfigError> {
    type Table = std::collections::BTreeMap<String, toml::Spanned<toml::Value>>;
    let table: Table = toml::from_str(text).map_err(|e| ConfigError::Toml {
        origin: origin.into(),
        // The parser's message quotes the line: at most a short excerpt of it.
        message: e
            .to_string()
            .trim_end()
            .lines()
            .map(|l| crate::text::excerpt_n(l, 80))
            .collect::<Vec<_>>()
            .join("\n"),
    })?;
    let mut items: Vec<(&String, &toml::Spanned<toml::Value>)> = table.iter().collect();
    items.sort_by_key(|(_, v)| v.span().start);
    let mut out = Vec::new();
    for (name, value) in items {
        let span = value.span();
        let line = text[..span.start].matches('\n').count() + 1;
        if name == "fit" && value.get_ref().is_table() {
            continue;
        }
        let key = Key::from_name(name).ok_or_else(|| ConfigError::UnknownKey {
            origin: origin.into(),
            line,
            key: name.clone(),
        })?;
        let text = match value.get_ref() {
            toml::Value::Integer(_) | toml::Value::Float(_) => text[span].replace('_', ""),
            toml::Value::String(s) => s.clone(),
            _ => {
                return Err(ConfigError::NotAValue {
                    origin: origin.into(),
                    line,
                    key,
                })
            }
        };
        out.push(Entry { key, line, text });
    }
    Ok(out)
}

/// Parses a TOML text of any keys over `base`: each value parsed and range-checked as the
/// unit does, the chassis keys checked together; the relations with the unit's options are
/// left to the unit (they depend on its current settings). Returns the settings and the keys
/// the file gives, in file order.
pub fn parse_settings(
    origin: &str,
    text: &str,
    base: Settings,
) -> Result<(Settings, Vec<Key>), ConfigError> {
    let entries = entries(origin, text)?;
    let mut s = base;
    for e in &entries {
        s.set(e.key, &e.text)
            .map_err(|error| ConfigError::Setting {
                origin: origin.into(),
                line: e.line,
                error,
            })?;
    }
    validate_chassis(&s.chassis).map_err(|error| ConfigError::Setting {
        origin: origin.into(),
        // The line of the key the error names, when the file gives it.
        line: entries
            .iter()
            .find(|e| Some(e.key) == error.key())
            .map_or(0, |e| e.line),
        error,
    })?;
    Ok((s, entries.iter().map(|e| e.key).collect()))
}

/// Parses a parameter TOML text (chassis keys only) over `base`; `file` names it in errors.
pub fn parse_params(file: &str, text: &str, base: ChassisParams) -> Result<ChassisParams> {
    for e in entries(file, text)? {
        chassis_key(file, e.line, e.key.name())?;
    }
    Ok(parse_settings(file, text, with_chassis(&base))?.0.chassis)
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

/// The geometry's correlations, which the unit checks together (the matrix they form must
/// stay consistent): one atomic `set`.
const CORRELATION_KEYS: [Key; 3] = [
    Key::DiametersCorrelation,
    Key::LeftTrackCorrelation,
    Key::RightTrackCorrelation,
];

/// The `set` lines that send a TOML text of any keys to the unit: every key the file gives, in
/// the unit's text form, the keys checked against each other in one atomic `set` each (the
/// related keys, [`RELATED_KEYS`], first; the geometry's correlations), then the rest in the
/// table's order, as many pairs per line as fit the unit's line
/// ([`odo_unit::console::MAX_LINE`] bytes, [`odo_unit::console::MAX_SET_PAIRS`] pairs). The
/// values are checked first as in [`parse_settings`] (over the defaults).
pub fn push_lines_of(origin: &str, text: &str) -> Result<Vec<String>> {
    let (s, given) = parse_settings(origin, text, Settings::DEFAULT)?;
    let pair = |k: Key| format!("{} {}", k.name(), value_text(&s, k));
    let group = |keys: &[Key]| -> Vec<String> {
        keys.iter()
            .filter(|k| given.contains(k))
            .map(|&k| pair(k))
            .collect()
    };
    let grouped: Vec<Key> = RELATED_KEYS.into_iter().chain(CORRELATION_KEYS).collect();
    let mut groups = vec![group(&RELATED_KEYS), group(&CORRELATION_KEYS)];
    groups.extend(
        Key::ALL
            .into_iter()
            .filter(|k| given.contains(k) && !grouped.contains(k))
            .map(|k| vec![pair(k)]),
    );
    groups.retain(|g| !g.is_empty());
    if groups.is_empty() {
        return Err(ConfigError::NothingToSend(origin.into()).into());
    }
    let mut lines: Vec<(String, usize)> = Vec::new();
    for g in groups {
        let words: usize = g.iter().map(|p| p.len() + 1).sum();
        match lines.last_mut() {
            Some((line, n))
                if *n + g.len() <= odo_unit::console::MAX_SET_PAIRS
                    && line.len() + words <= odo_unit::console::MAX_LINE =>
            {
                for p in &g {
                    line.push(' ');
                    line.push_str(p);
                }
                *n += g.len();
            }
            _ => lines.push((format!("set {}", g.join(" ")), g.len())),
        }
    }
    Ok(lines.into_iter().map(|(l, _)| l).collect())
}

/// [`push_lines_of`] a file.
pub fn push_lines(path: &Path) -> Result<Vec<String>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    push_lines_of(&path.display().to_string(), &text)
}

/// The settings in a unit's `get` reply (`key = value` lines; an `ok` line and unknown
/// lines are errors, so nothing is dropped): each value parsed as the unit does, over the
/// defaults. Returns the settings and the keys given, in reply order.
pub fn parse_get_reply(reply: &str) -> Result<(Settings, Vec<Key>), ConfigError> {
    let mut s = Settings::DEFAULT;
    let mut keys = Vec::new();
    for (i, line) in reply.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || (i == 0 && line == "ok") {
            continue;
        }
        let (name, value) = line.split_once(" = ").unwrap_or((line, ""));
        let key = Key::from_name(name).ok_or_else(|| ConfigError::UnknownKey {
            origin: "get reply".into(),
            line: i + 1,
            key: name.into(),
        })?;
        s.set(key, value).map_err(|error| ConfigError::Setting {
            origin: "get reply".into(),
            line: i + 1,
            error,
        })?;
        keys.push(key);
    }
    Ok((s, keys))
}

/// A TOML text of the `keys` of `s`, in the table's order, values in the unit's text form
/// (words quoted); `comment` lines first. [`push_lines_of`] reads it back bit for bit.
pub fn render_settings(s: &Settings, keys: &[Key], comment: &str) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        let _ = writeln!(out, "# {line}");
    }
    for k in Key::ALL.into_iter().filter(|k| keys.contains(k)) {
        let v = value_text(s, k);
        let _ = match k.info().kind {
            odo_unit::settings::Kind::Word(_) => writeln!(out, "{} = \"{v}\"", k.name()),
            _ => writeln!(out, "{} = {v}", k.name()),
        };
    }
    out
}

/// The keys a parameter file lists: the main keys, and any other chassis key whose value
/// differs from the designed one.
pub fn keys_to_write(p: &ChassisParams) -> Vec<Key> {
    let (s, d) = (with_chassis(p), with_chassis(&ChassisParams::DESIGNED));
    chassis_keys()
        .filter(|k| MAIN_KEYS.contains(k) || s.get(*k) != d.get(*k))
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

/// Renders a parameter file: a comment header, the chassis keys at top level, then `[fit]`.
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
    let mut keys = keys_to_write(p);
    keys.extend(always.iter().filter_map(|k| Key::from_name(k)));
    let mut s = render_settings(&with_chassis(p), &keys, comment);
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
    fn every_chassis_key_roundtrips() {
        let mut p = ChassisParams::DESIGNED;
        let mut sets = Vec::new();
        for (i, k) in chassis_keys().enumerate() {
            let v = match k {
                Key::TicksPerRev => "4096".to_string(),
                Key::UncertaintyModel => "covariance".to_string(),
                Key::LeftDiameter | Key::RightDiameter | Key::TrackWidth => {
                    format!("0.{}", 250 + i)
                }
                _ => format!("{}e-4", i + 1),
            };
            sets.push(format!("{}={v}", k.name()));
        }
        apply_sets(&mut p, &sets).unwrap();
        validated(p, "test").unwrap();
        let text = render_params(&p, "test", &[("initial_heading", FitValue::Num(0.5))]);
        let back = parse_params("x.toml", &text, ChassisParams::DESIGNED).unwrap();
        assert_eq!(back, p);
        // The 24th chassis key (`kappa_diff_corr` is the 12th).
        assert_eq!(chassis_value_text(&back, Key::RightSin3), "0.0024");
        assert_eq!(chassis_value_text(&back, Key::KappaDiffCorr), "0.0012");
    }

    /// Parameter files (`simulate --truth-out`, `calibrate`) write every key as a plain
    /// decimal, never an exponent, however small, and read back bit for bit.
    #[test]
    fn small_values_are_written_as_plain_decimals() {
        let mut p = ChassisParams::DESIGNED;
        p.delta_left = 1e-10;
        p.kappa_right = f32::from_bits(1); // the smallest subnormal
        p.left_wheel.cos[0] = -1e-12;
        let text = render_params(&p, "truth", &[]);
        assert!(text.contains("\ndelta_left = 0.0000000001\n"), "{text}");
        assert!(text.contains(&format!("\nkappa_right = 0.{}1\n", "0".repeat(44))));
        assert!(text.contains("\nleft_cos1 = -0.000000000001\n"), "{text}");
        for line in text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.is_empty())
        {
            let (_, v) = line.split_once(" = ").expect("key = value");
            assert!(v.starts_with('"') || !v.contains(['e', 'E']), "{line}");
        }
        let back = parse_params("t.toml", &text, ChassisParams::DESIGNED).unwrap();
        assert_eq!(
            with_chassis(&back).to_bytes(),
            with_chassis(&p).to_bytes(),
            "bit for bit"
        );
    }

    fn error_of(r: Result<ChassisParams>) -> ConfigError {
        r.unwrap_err()
            .downcast::<ConfigError>()
            .expect("a ConfigError")
    }

    #[test]
    fn errors_name_file_line_and_key() {
        let d = ChassisParams::DESIGNED;
        let e = error_of(parse_params("c.toml", "left_diameter = 0.26\nfoo = 1\n", d));
        assert!(
            matches!(&e, ConfigError::UnknownKey { line: 2, key, .. } if key == "foo"),
            "{e:?}"
        );
        assert!(
            e.to_string().starts_with("c.toml:2: unknown key `foo`"),
            "{e}"
        );
        let e = error_of(parse_params("c.toml", "track_width = 99.0\n", d));
        assert_eq!(
            e,
            ConfigError::Setting {
                origin: "c.toml".into(),
                line: 1,
                error: SettingError::OutOfRange(Key::TrackWidth)
            }
        );
        assert!(e.to_string().starts_with("c.toml:1: track_width"), "{e}");
        let e = error_of(parse_params("c.toml", "track_width = \n", d));
        assert!(matches!(&e, ConfigError::Toml { origin, .. } if origin == "c.toml"));
        let e = error_of(parse_params("c.toml", "ticks_per_rev = 1.5\n", d));
        assert!(
            matches!(
                e,
                ConfigError::Setting {
                    error: SettingError::BadNumber(Key::TicksPerRev),
                    ..
                }
            ),
            "{e:?}"
        );
        // A relation between chassis keys: reported at the line of the key it names.
        let e = error_of(parse_params(
            "c.toml",
            "track_width = 0.5\nticks_per_rev = 100\n",
            d,
        ));
        assert_eq!(
            e,
            ConfigError::Setting {
                origin: "c.toml".into(),
                line: 2,
                error: SettingError::Chassis(Key::TicksPerRev)
            }
        );
        // Unit options belong to `config push`, not to parameter files.
        let e = error_of(parse_params("c.toml", "\nrate = 100\n", d));
        assert!(
            matches!(
                e,
                ConfigError::NotChassis {
                    line: 2,
                    key: Key::Rate,
                    ..
                }
            ),
            "{e:?}"
        );
        let e = error_of(parse_params("c.toml", "left_diameter = true\n", d));
        assert!(matches!(e, ConfigError::NotAValue { line: 1, .. }), "{e:?}");
        let mut p = ChassisParams::DESIGNED;
        let e = apply_sets(&mut p, &["left_cos4=0.1".into()]).unwrap_err();
        assert!(
            matches!(e.downcast_ref(), Some(ConfigError::UnknownKey { .. })),
            "{e}"
        );
        let e = apply_sets(&mut p, &["left_diameter".into()]).unwrap_err();
        assert!(
            matches!(e.downcast_ref(), Some(ConfigError::NotAnAssignment(_))),
            "{e}"
        );
        assert_eq!(p, ChassisParams::DESIGNED);
        apply_sets(&mut p, &["left_diameter=0.3".into()]).unwrap();
        assert_eq!(p.left_diameter, 0.3);
    }

    /// TOML numbers reach the unit's parser as written: an f32 key gets the f32 nearest to
    /// the decimal (not the f32 nearest to the f64 nearest to it), `-0` keeps its sign, and
    /// digit separators are allowed.
    #[test]
    fn toml_numbers_are_parsed_as_the_unit_parses_them() {
        // 1.00000005960464477539062500001 lies just above the halfway point between the
        // f32 values 1 and 1 + 2^-23; its nearest f64 is the halfway point itself, which
        // rounds (to even) to 1: parsing through f64 gives the wrong f32.
        let text = "1.00000005960464477539062500001";
        assert_eq!(text.parse::<f64>().unwrap() as f32, 1.0);
        let s = Settings::DEFAULT;
        let mut unit = s;
        unit.set(Key::MaxWheelSpeed, text).unwrap();
        assert_eq!(unit.max_wheel_speed, 1.0 + f32::EPSILON);
        let (got, keys) = parse_settings(
            "t.toml",
            &format!("max_wheel_speed = {text}\nleft_cos1 = -0\nticks_per_rev = 20_000\n"),
            s,
        )
        .unwrap();
        assert_eq!(keys, [Key::MaxWheelSpeed, Key::LeftCos1, Key::TicksPerRev]);
        assert_eq!(
            got.max_wheel_speed.to_bits(),
            unit.max_wheel_speed.to_bits()
        );
        assert_eq!(got.chassis.left_wheel.cos[0].to_bits(), (-0.0f32).to_bits());
        assert_eq!(got.chassis.ticks_per_rev, 20_000);
    }

    #[test]
    fn errors_quote_binary_files_short() {
        let bin: String = (0..3000u32)
            .map(|i| char::from_u32(i % 0x5f + 0x20).unwrap_or('?'))
            .filter(|c| *c != '\n')
            .collect();
        let e = parse_params("b.toml", &bin, ChassisParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("b.toml: "), "{e}");
        assert!(e.lines().all(|l| l.chars().count() < 120), "{e}");
        let e = parse_params(
            "k.toml",
            &format!("{} = 1\n", "k".repeat(500)),
            ChassisParams::default(),
        )
        .unwrap_err()
        .to_string();
        // The key is quoted as a short excerpt; the list of known keys follows it.
        let quoted = e
            .split_once("unknown key `")
            .and_then(|(_, rest)| rest.split_once('`'))
            .map(|(key, _)| key)
            .unwrap_or_else(|| panic!("{e}"));
        assert!(
            quoted.starts_with("kkk") && quoted.chars().count() <= 45,
            "{e}"
        );
        assert!(!e.contains(&"k".repeat(100)), "{e}");
    }
}
