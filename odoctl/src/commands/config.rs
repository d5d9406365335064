//! `odoctl config`: reads and changes the unit's settings.

use std::process::ExitCode;

use anyhow::{bail, Context, Result};

use crate::cli::{ConfigAction, ConfigArgs};
use crate::config as cfg;
use crate::link::{escape_control, open, Session, REPLY_TIMEOUT};

/// `odoctl config`: prints the unit's replies; exit code 1 on an error reply.
pub fn run(a: &ConfigArgs) -> Result<ExitCode> {
    let (port, baud, action) = (&a.port.port, a.port.baud, &a.action);
    // A key or value is one word: `set rate "50 baud 9600"` would send two pairs.
    let one_word = |what: &str, w: &str| {
        if w.is_empty() || w.chars().any(|c| c.is_whitespace() || c.is_control()) {
            bail!(
                "{what} `{}` must be one word (no spaces or control characters)",
                escape_control(w)
            );
        }
        Ok(())
    };
    match action {
        ConfigAction::Get { key: Some(k) } => one_word("key", k)?,
        ConfigAction::Set { key, value } => {
            one_word("key", key)?;
            one_word("value", value)?;
        }
        _ => {}
    }
    let lines: Vec<String> = match action {
        ConfigAction::Get { key: None } => vec!["get".into()],
        ConfigAction::Get { key: Some(k) } => vec![format!("get {k}")],
        ConfigAction::Set { key, value } => vec![format!("set {key} {value}")],
        ConfigAction::Save => vec!["save".into()],
        ConfigAction::Push { file, no_save } => {
            let mut l = cfg::push_lines(file)?;
            if !no_save {
                l.push("save".into());
            }
            l
        }
        ConfigAction::Pull { .. } => vec!["get".into()],
        ConfigAction::Raw { line } => vec![line.join(" ")],
    };
    if lines.iter().any(|l| l.contains('\n') || l.contains('\r')) {
        bail!("a command must be one line");
    }
    let mut s = Session::new(open(port, baud)?, None)?;
    for line in &lines {
        let (ok, text) = s.command(line, REPLY_TIMEOUT)?;
        crate::outln!("> {line}");
        for l in text.lines() {
            crate::outln!("{}", escape_control(l));
        }
        if !ok {
            eprintln!("odoctl: the unit rejected `{line}`");
            return Ok(ExitCode::FAILURE);
        }
        if let ConfigAction::Pull { file: path } = action {
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
