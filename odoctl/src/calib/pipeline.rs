//! The two-core pipeline of the sensitivity pass: a second thread runs the core integrator
//! while this one follows the sensitivities.

use odo_unit::odometry::{ChassisParams, Integrator, Pose, PoseStep};

use crate::csvio::Sample;
use crate::replay::{counts, index_refs};

use super::sensitivity::{PoseSensitivity, SensitivityTracker};

/// The cores this process may run on, asked once (the question reads the scheduler's
/// affinity and cgroup limits: too slow to ask at every integration).
pub fn cores() -> usize {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Shortest stretch (samples) that `Run::integrate_with_sensitivity` spreads over two cores:
/// below it, the thread costs more than it saves.
pub const PIPELINE_MIN_SAMPLES: usize = 20_000;

/// Samples per chunk handed from the integrating thread to the sensitivity thread (80 bytes
/// each: 320 KiB, in the caches).
pub(crate) const PIPELINE_CHUNK: usize = 4096;

/// Chunks in flight between the two threads at most.
const PIPELINE_DEPTH: usize = 4;

/// One sample as the integrating thread hands it on: the step's motion, when integrated, and
/// at a match its index and the pose there.
struct PipelineItem {
    motion: Option<PoseStep>,
    at: Option<(usize, Pose)>,
}

/// The sensitivity pass over matches `a..=b` (`stretch`) as a pipeline: a scoped thread runs
/// `integ` (started at match `a`) over `samples` and hands each sample's motion
/// ([`PoseStep`]) and, at the `matches`, the pose on, in chunks of [`PIPELINE_CHUNK`] samples
/// (recycled); this thread follows the sensitivities of `params` and calls `visit(k, &pose,
/// &sensitivity)` at every match `k` in `a+1..=b`.
pub(crate) fn follow_sensitivities(
    mut integ: Integrator,
    params: &ChassisParams,
    samples: &[Sample],
    matches: &[(usize, usize)],
    (a, b): (usize, usize),
    mut visit: impl FnMut(usize, &Pose, &PoseSensitivity),
) {
    let (sa, sb) = (matches[a].0, matches[b].0);
    let (full, chunks) = std::sync::mpsc::sync_channel::<Vec<PipelineItem>>(PIPELINE_DEPTH);
    let (recycle, empty) = std::sync::mpsc::channel::<Vec<PipelineItem>>();
    let mut tracker = SensitivityTracker::new(params);
    std::thread::scope(|scope| {
        scope.spawn(move || {
            let mut k = a + 1;
            let mut chunk = Vec::with_capacity(PIPELINE_CHUNK);
            for (i, s) in (sa + 1..=sb).zip(&samples[sa + 1..=sb]) {
                let motion = integ.step_pose(counts(s), index_refs(s)).1;
                let at = (k <= b && matches[k].0 == i).then(|| {
                    k += 1;
                    (k - 1, integ.pose())
                });
                chunk.push(PipelineItem { motion, at });
                if chunk.len() == PIPELINE_CHUNK {
                    if full.send(chunk).is_err() {
                        return;
                    }
                    chunk = empty
                        .try_recv()
                        .unwrap_or_else(|_| Vec::with_capacity(PIPELINE_CHUNK));
                }
            }
            if !chunk.is_empty() {
                let _ = full.send(chunk);
            }
        });
        for mut chunk in chunks {
            for item in &chunk {
                if let Some(m) = &item.motion {
                    tracker.step(m);
                }
                if let Some((k, pose)) = &item.at {
                    visit(*k, pose, &tracker.sens);
                }
            }
            chunk.clear();
            let _ = recycle.send(chunk);
        }
    });
}
