//! TUM trajectory files (the format of the TUM RGB-D benchmark and of `evo`): one pose a line,
//! `timestamp tx ty tz qx qy qz qw` separated by spaces or tabs, timestamp in seconds, position
//! in metres, the orientation as a quaternion; blank lines and lines starting with `#` are
//! skipped.

use anyhow::{bail, Result};

use super::trajectory::{self, TrajectoryPose};

/// True when `line` (trimmed, not a comment) is a TUM pose: exactly 8 numbers.
pub fn is_pose_line(line: &str) -> bool {
    let mut n = 0;
    for t in line.split_whitespace() {
        if t.parse::<f64>().is_err() {
            return false;
        }
        n += 1;
    }
    n == 8
}

/// Parses a TUM file; `file` names it in messages. A line that is not 8 numbers, a stamp or
/// position that is not finite, a quaternion without a yaw, or a stamp not after the previous
/// one is an error naming `FILE:LINE`.
pub fn parse(file: &str, text: &str) -> Result<Vec<TrajectoryPose>> {
    let mut poses = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim().trim_start_matches('\u{feff}');
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|t| t.parse::<f64>())
            .collect::<Result<_, _>>()
            .unwrap_or_default();
        let [t, x, y, z, qx, qy, qz, qw] = v[..] else {
            bail!(
                "{file}:{}: expected `timestamp tx ty tz qx qy qz qw` (8 numbers), got `{line}`",
                i + 1
            );
        };
        poses.push(TrajectoryPose {
            t,
            position: [x, y, z],
            orientation: [qx, qy, qz, qw],
            line: i + 1,
        });
    }
    trajectory::check(file, "line", &poses).map_err(|e| {
        // `FILE: line N:` reads as `FILE:N:` like the other readers.
        anyhow::anyhow!(e.to_string().replacen(": line ", ":", 1))
    })?;
    Ok(poses)
}

/// Writes poses as a TUM file: stamps with nine decimals, positions with six, quaternions
/// with nine.
pub fn write(w: &mut impl std::io::Write, poses: &[TrajectoryPose]) -> std::io::Result<()> {
    writeln!(w, "# timestamp tx ty tz qx qy qz qw")?;
    for p in poses {
        let [x, y, z] = p.position;
        let [qx, qy, qz, qw] = p.orientation;
        writeln!(
            w,
            "{:.9} {x:.6} {y:.6} {z:.6} {qx:.9} {qy:.9} {qz:.9} {qw:.9}",
            p.t
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_poses_comments_and_tabs() {
        let text = "# evo\n\n1700000000.000000 1 2 0.3 0 0 0 1\n1700000000.01\t1.1 2 0.3 0 0 0.0998 0.995\n";
        let p = parse("a.tum", text).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].line, p[1].line), (3, 4));
        assert_eq!(p[1].position, [1.1, 2.0, 0.3]);
        assert_eq!(p[1].orientation, [0.0, 0.0, 0.0998, 0.995]);
        let mut back = Vec::new();
        write(&mut back, &p).unwrap();
        let again = parse("b.tum", std::str::from_utf8(&back).unwrap()).unwrap();
        assert_eq!(again.len(), 2);
        assert!((again[1].t - p[1].t).abs() < 1e-6);
    }

    #[test]
    fn bad_lines_are_errors_naming_file_and_line() {
        let table = [
            ("0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0\n", "a.tum:2: expected"),
            ("0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 0 x\n", "a.tum:2: expected"),
            ("0 1 2 3 0 0 0 1\n0 1 2 3 0 0 0 1\n", "a.tum:2: stamp"),
            ("0 1 2 3 0 0 0 1\n-1 1 2 3 0 0 0 1\n", "a.tum:2: stamp"),
            (
                "0 1 2 3 0 0 0 1\n1 1 2 3 nan 0 0 1\n",
                "a.tum:2: quaternion",
            ),
            ("0 1 2 3 0 0 0 0\n", "a.tum:1: quaternion"),
            ("0 1 nan 3 0 0 0 1\n", "a.tum:1: stamp or position"),
            ("# only a comment\n", "a.tum: 0 poses"),
        ];
        for (text, want) in table {
            let e = parse("a.tum", text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        assert!(is_pose_line("1 2 3 4 5 6 7 8"));
        assert!(!is_pose_line("1 2 3 4 5 6 7"));
        assert!(!is_pose_line("t,x,y"));
    }
}
