//! `odoctl umbmark` on simulated square tests: five clockwise and five counter-clockwise squares
//! of 4 m and a 10 m straight, end positions measured to 2 mm, by a chassis whose diameters and
//! track width differ from the designed ones; the estimates lie within 3 reported standard
//! errors over several seeds, and a measurements file that does not match its recordings is
//! refused.

mod common;

use std::f64::consts::FRAC_PI_2;
use std::io::Write as _;

use odoctl::csvio;
use odoctl::simulate::{default_truth, simulate, Rng, Segment, SimOptions, SimSettings};

/// Writes a run of `segments` and returns its true end (forward, left, heading change
/// counter-clockwise) from the start.
fn run(dir: &std::path::Path, name: &str, segments: Vec<Segment>, seed: u64) -> (f64, f64, f64) {
    let mut plan = Vec::new();
    plan.extend(segments);
    let sim = simulate(&SimOptions {
        truth: default_truth(),
        segments: plan,
        settings: SimSettings {
            start: (0.0, 0.0, 0.0),
            seed,
            ..SimSettings::default()
        },
    });
    let mut w = std::io::BufWriter::new(std::fs::File::create(dir.join(name)).unwrap());
    csvio::write_samples(&mut w, &sim.samples, csvio::SamplesLayout::Counts).unwrap();
    w.flush().unwrap();
    let (x, y, h) = *sim.truth.last().unwrap();
    (y, -x, -odoctl::stats::wrap_angle(h))
}

fn square(turn: f64) -> Vec<Segment> {
    (0..4)
        .flat_map(|_| [Segment::Straight(4.0), Segment::Spin(turn)])
        .collect()
}

/// Simulates the test for `seed` and writes its measurements file; returns its path.
fn square_test(seed: u64, extra_run: Option<&str>) -> std::path::PathBuf {
    let d = common::scratch(&format!("umbmark{seed}"));
    let mut rng = Rng::new(seed ^ 0xAB);
    let sigma = 0.002;
    let heading_sigma = 0.5f64;
    let mut toml = format!("side = 4.0\nsigma = {sigma}\nheading_sigma_deg = {heading_sigma}\n");
    // The squares' end headings measured too, the straight's not.
    let mut entry = |name: &str, dir: &str, (f, l, h): (f64, f64, f64), rng: &mut Rng| {
        let (f, l) = (f + sigma * rng.normal(), l + sigma * rng.normal());
        toml.push_str(&format!(
            "\n[[run]]\nsamples = \"{name}\"\ndirection = \"{dir}\"\nforward = {f}\nleft = {l}\n"
        ));
        if dir != "straight" {
            let h = h.to_degrees() + heading_sigma * rng.normal();
            toml.push_str(&format!("heading_deg = {h}\n"));
        }
    };
    for k in 0..5u64 {
        let cw = run(&d, &format!("cw{k}.csv"), square(FRAC_PI_2), seed * 100 + k);
        entry(&format!("cw{k}.csv"), "cw", cw, &mut rng);
        let ccw = run(
            &d,
            &format!("ccw{k}.csv"),
            square(-FRAC_PI_2),
            seed * 100 + 50 + k,
        );
        entry(&format!("ccw{k}.csv"), "ccw", ccw, &mut rng);
    }
    let s = run(
        &d,
        "straight.csv",
        vec![Segment::Straight(10.0)],
        seed * 100 + 99,
    );
    entry("straight.csv", "straight", s, &mut rng);
    if let Some(e) = extra_run {
        toml.push_str(e);
    }
    let p = d.join("measurements.toml");
    std::fs::write(&p, toml).unwrap();
    p
}

#[test]
fn square_test_estimates_within_their_standard_errors() {
    let t = default_truth();
    let truth = [t.left_diameter, t.right_diameter, t.track_width];
    let mut worst = [0.0f64; 3];
    for seed in 1..=4 {
        let m = square_test(seed, None);
        let out = m.with_file_name("out.toml");
        let stdout = common::success_stdout(&common::odoctl(&[
            "umbmark",
            "--measurements",
            m.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]));
        assert!(stdout.contains("Ed = right/left diameter"), "{stdout}");
        let tab: toml::Table = common::read(&out).parse().unwrap();
        let fit = tab["fit"].as_table().unwrap();
        let est =
            ["left_diameter", "right_diameter", "track_width"].map(|k| tab[k].as_float().unwrap());
        let se = ["left_diameter_se", "right_diameter_se", "track_width_se"]
            .map(|k| fit[k].as_float().unwrap());
        eprintln!(
            "seed {seed}: errors {:+.1} {:+.1} {:+.1} um, se {:.1} {:.1} {:.1} um, ratio error {:+.1e}",
            (est[0] - truth[0]) * 1e6,
            (est[1] - truth[1]) * 1e6,
            (est[2] - truth[2]) * 1e6,
            se[0] * 1e6,
            se[1] * 1e6,
            se[2] * 1e6,
            est[1] / est[0] - truth[1] / truth[0]
        );
        for k in 0..3 {
            let z = (est[k] - truth[k]) / se[k];
            worst[k] = worst[k].max(z.abs());
            assert!(
                z.abs() <= 3.0,
                "seed {seed} parameter {k}: {est:?} se {se:?}"
            );
        }
    }
    eprintln!("largest |error| / se: {worst:.2?}");
}

#[test]
fn runs_that_do_not_match_their_recordings_are_refused() {
    // A clockwise square given as counter-clockwise.
    let m = square_test(
        9,
        Some("\n[[run]]\nsamples = \"cw0.csv\"\ndirection = \"ccw\"\nforward = 0.0\nleft = 0.0\n"),
    );
    let out = m.with_file_name("bad.toml");
    let o = common::odoctl(&[
        "umbmark",
        "--measurements",
        m.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    // The entry's line: the last `samples = "cw0.csv"` of the file.
    let text = std::fs::read_to_string(&m).unwrap();
    let line = text
        .lines()
        .enumerate()
        .filter(|(_, l)| l.trim() == "samples = \"cw0.csv\"")
        .last()
        .unwrap()
        .0
        + 1;
    assert!(
        !o.status.success()
            && e.contains(&format!(":{line}: run 12 (cw0.csv)"))
            && e.contains("does not match"),
        "{e}"
    );
    assert!(!out.exists());
}
