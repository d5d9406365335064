//! Booting the firmware's `qemu` image for the end-to-end tests; shared by `host-tests/` and
//! `odoctl/tests/` (included there by path).
//!
//! The image is `$ODO_QEMU_IMAGE` or `<repo>/target/qemu/thumbv7em-none-eabihf/release/odo-unit`
//! (`cargo build --release --features qemu --target-dir target/qemu`); QEMU is
//! `$QEMU_SYSTEM_ARM` or `qemu-system-arm` on the PATH. Without either the test is skipped
//! with a message, unless `ODO_QEMU_REQUIRED=1` (as in CI), which makes it fail.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// QEMU running the image, killed when dropped. Its USART2 (the host link) is a TCP server
/// on 127.0.0.1:`port` that waits for one connection before the firmware runs.
pub struct Qemu {
    child: Child,
    /// TCP port of the unit's USART2.
    pub port: u16,
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The `qemu` image of the repository at `repo`.
pub fn image(repo: &Path) -> PathBuf {
    std::env::var_os("ODO_QEMU_IMAGE")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("target/qemu/thumbv7em-none-eabihf/release/odo-unit"))
}

/// `qemu-system-arm`, if installed.
pub fn qemu_binary() -> Option<PathBuf> {
    if let Some(q) = std::env::var_os("QEMU_SYSTEM_ARM") {
        return Some(PathBuf::from(q));
    }
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|d| Path::new(d).join("qemu-system-arm"))
        .find(|p| p.is_file())
}

/// Boots the image of `repo` on `netduinoplus2` with `-icount shift=0,sleep=off`
/// (deterministic, faster than real time), or returns `None` after saying why `test` is
/// skipped; panics instead when `ODO_QEMU_REQUIRED=1`.
pub fn boot(repo: &Path, test: &str) -> Option<Qemu> {
    let required = std::env::var("ODO_QEMU_REQUIRED").is_ok_and(|v| v == "1");
    let image = image(repo);
    let missing = match qemu_binary() {
        None => Some("qemu-system-arm not found (apt-get install qemu-system-arm)".to_string()),
        Some(_) if !image.is_file() => Some(format!(
            "no image at {} (cargo build --release --features qemu --target-dir target/qemu)",
            image.display()
        )),
        Some(_) => None,
    };
    if let Some(why) = missing {
        assert!(!required, "{why}, and ODO_QEMU_REQUIRED=1");
        eprintln!("SKIPPED {test}: {why}");
        return None;
    }
    let qemu = qemu_binary()?;
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free local port")
        .port();
    let child = Command::new(qemu)
        .args([
            "-machine",
            "netduinoplus2",
            "-display",
            "none",
            "-nodefaults",
        ])
        .args(["-icount", "shift=0,sleep=off"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-serial", "null", "-serial"])
        .arg(format!("tcp:127.0.0.1:{port},server=on,wait=on"))
        .arg("-kernel")
        .arg(&image)
        .stdin(Stdio::null())
        .stdout(Stdio::null()) // defmt frames over semihosting (binary)
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start QEMU");
    Some(Qemu { child, port })
}
