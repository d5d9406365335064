//! `odoctl bridge`: the live pose published on ROS 2 over DDS, and over the Foxglove WebSocket
//! protocol with `--foxglove`.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;

use crate::cli::BridgeArgs;
use crate::ros::bridge::{self, BridgeOptions};
use crate::ros::names::RosNames;

/// `odoctl bridge`.
pub fn run(a: &BridgeArgs) -> Result<ExitCode> {
    let secs = |what: &str, v: f64| {
        Duration::try_from_secs_f64(v)
            .map_err(|_| anyhow::anyhow!("--{what} {v}: not a duration in seconds"))
    };
    if let Some(target) = &a.mavlink {
        return crate::mavlink::bridge(a, target);
    }
    bridge::run(&BridgeOptions {
        port: a.port.port.clone(),
        baud: a.port.baud,
        params: crate::config::load(a.params.config.as_deref(), &a.params.sets)?,
        duration: a.duration.map(|d| secs("duration", d)).transpose()?,
        count: a.count,
        retry: secs("retry", a.retry)?,
        foxglove: a.foxglove.clone(),
        dds: !a.no_dds,
        names: RosNames::resolve(&a.ros.options(&a.node_name))?,
    })
}
