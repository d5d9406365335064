//! How the bridge's DDS participant is discovered, from the environment as ROS 2 reads it
//! (rcl, Jazzy): `ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`, `ROS_STATIC_PEERS` and the
//! older `ROS_LOCALHOST_ONLY`. docs/ROS.md, *Discovery*, says what each range does here.

use anyhow::{anyhow, Result};

/// `ROS_AUTOMATIC_DISCOVERY_RANGE`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Range {
    /// No discovery with other processes.
    Off,
    /// Processes on this host only.
    Localhost,
    /// The subnet (multicast): ROS 2's default.
    Subnet,
    /// The DDS implementation's own default.
    SystemDefault,
}

/// The discovery settings of the environment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Discovery {
    /// `ROS_DOMAIN_ID` (0..=232), default 0.
    pub domain: u16,
    /// The range in force.
    pub range: Range,
    /// `ROS_STATIC_PEERS` (`;`-separated addresses), as given.
    pub static_peers: Vec<String>,
    /// What the environment asked that is not done, to be reported (the `ROS_...` name and why).
    pub warnings: Vec<String>,
}

/// The domain of `ROS_DOMAIN_ID` (`None`: unset or empty).
fn domain(v: Option<&str>) -> Result<u16> {
    match v.map(str::trim).filter(|v| !v.is_empty()) {
        None => Ok(0),
        Some(v) => v
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= 232)
            .ok_or_else(|| anyhow!("ROS_DOMAIN_ID `{v}` is not a domain (0..=232)")),
    }
}

impl Discovery {
    /// Reads the settings from `var` (the environment, or a table in tests) the way rcl does:
    /// `ROS_LOCALHOST_ONLY=1` (its first character `1`) means the localhost range and no
    /// static peers, whatever the other two say; an empty or unset range is `SUBNET`; an
    /// unknown one is taken as `LOCALHOST` with a warning (rcl's choice); static peers are
    /// read except with `OFF`, and used with `SUBNET` and `LOCALHOST`.
    pub fn from_env(var: impl Fn(&str) -> Option<String>) -> Result<Self> {
        let domain = domain(var("ROS_DOMAIN_ID").as_deref())?;
        let mut warnings = Vec::new();
        let localhost_only = var("ROS_LOCALHOST_ONLY").filter(|v| !v.is_empty());
        let range_text = var("ROS_AUTOMATIC_DISCOVERY_RANGE").unwrap_or_default();
        let range = if localhost_only
            .as_deref()
            .is_some_and(|v| v.starts_with('1'))
        {
            Range::Localhost
        } else {
            match range_text.as_str() {
                "" | "SUBNET" => Range::Subnet,
                "OFF" => Range::Off,
                "LOCALHOST" => Range::Localhost,
                "SYSTEM_DEFAULT" => Range::SystemDefault,
                other => {
                    warnings.push(format!(
                        "ROS_AUTOMATIC_DISCOVERY_RANGE `{other}` is none of OFF, LOCALHOST, SUBNET, SYSTEM_DEFAULT: assuming LOCALHOST, as ROS 2 does"
                    ));
                    Range::Localhost
                }
            }
        };
        let peers: Vec<String> = var("ROS_STATIC_PEERS")
            .unwrap_or_default()
            .split(';')
            .map(str::trim)
            .filter(|p| !p.is_empty())
            .map(String::from)
            .collect();
        let ignored = |why: &str| format!("ROS_STATIC_PEERS ignored: {why}");
        let static_peers = match range {
            _ if peers.is_empty() => peers,
            _ if localhost_only
                .as_deref()
                .is_some_and(|v| v.starts_with('1')) =>
            {
                warnings.push(ignored("ROS_LOCALHOST_ONLY=1"));
                Vec::new()
            }
            Range::Off => {
                warnings.push(ignored("the discovery range is OFF"));
                Vec::new()
            }
            Range::SystemDefault => {
                warnings.push(ignored("the discovery range is SYSTEM_DEFAULT"));
                Vec::new()
            }
            Range::Subnet | Range::Localhost => peers,
        };
        Ok(Self {
            domain,
            range,
            static_peers,
            warnings,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(pairs: &[(&str, &str)]) -> Result<Discovery> {
        let owned: Vec<(String, String)> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        Discovery::from_env(move |k| owned.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone()))
    }

    #[test]
    fn ranges_table() {
        let r = |pairs: &[(&str, &str)]| env(pairs).unwrap().range;
        assert_eq!(r(&[]), Range::Subnet);
        assert_eq!(r(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "")]), Range::Subnet);
        assert_eq!(r(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")]), Range::Off);
        assert_eq!(
            r(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")]),
            Range::Localhost
        );
        assert_eq!(
            r(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "SYSTEM_DEFAULT")]),
            Range::SystemDefault
        );
        // Humble's variable wins over the range.
        assert_eq!(
            r(&[
                ("ROS_LOCALHOST_ONLY", "1"),
                ("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET")
            ]),
            Range::Localhost
        );
        assert_eq!(r(&[("ROS_LOCALHOST_ONLY", "0")]), Range::Subnet);
        // Unknown: LOCALHOST with a warning; the names are case-sensitive, as in rcl.
        let d = env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "localhost")]).unwrap();
        assert_eq!(d.range, Range::Localhost);
        assert!(d.warnings[0].contains("assuming LOCALHOST"));
    }

    #[test]
    fn static_peers_and_domain() {
        let d = env(&[
            ("ROS_STATIC_PEERS", " 192.168.0.2 ;;robot.local;"),
            ("ROS_DOMAIN_ID", "7"),
        ])
        .unwrap();
        assert_eq!(d.static_peers, ["192.168.0.2", "robot.local"]);
        assert_eq!(d.domain, 7);
        for (k, v) in [
            ("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF"),
            ("ROS_AUTOMATIC_DISCOVERY_RANGE", "SYSTEM_DEFAULT"),
            ("ROS_LOCALHOST_ONLY", "1"),
        ] {
            let d = env(&[(k, v), ("ROS_STATIC_PEERS", "10.0.0.1")]).unwrap();
            assert!(d.static_peers.is_empty(), "{k}={v}");
            assert!(
                d.warnings[0].contains("ROS_STATIC_PEERS ignored"),
                "{k}={v}"
            );
        }
        for bad in ["233", "-1", "x"] {
            assert!(env(&[("ROS_DOMAIN_ID", bad)]).is_err(), "{bad}");
        }
        assert_eq!(env(&[("ROS_DOMAIN_ID", " ")]).unwrap().domain, 0);
    }
}
