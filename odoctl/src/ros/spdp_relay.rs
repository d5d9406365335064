//! Unicast discovery peers for RustDDS, which has no peer list of its own: its participant
//! announcements (SPDP) reach the well-known ports of the first participants on 127.0.0.1,
//! one of which this relay holds; the relay sends each announcement of our participant on to
//! the well-known discovery ports of the peers (`ROS_STATIC_PEERS`) and of the local
//! addresses other participants announce themselves from (a Cyclone DDS participant
//! configured for `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` accepts announcements only on the
//! interface it uses, which is not the loopback one when the host has another).

use std::collections::BTreeSet;
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, Result};

/// RTPS well-known port numbers (RTPS 2.x, 9.6.2.3): PB, DG, PG and d0/d1.
const PB: u32 = 7400;
const DG: u32 = 250;
const PG: u32 = 2;
const D1: u32 = 10;
/// Participant indices RustDDS announces itself to on 127.0.0.1 (its
/// `SPDP_LOCALHOST_PEER_COUNT`); the relay takes the highest free one.
const RUSTDDS_LOCAL_PEERS: u32 = 12;
/// Participant indices the relay sends to on each address: Cyclone DDS's range as
/// rmw_cyclonedds configures it (`MaxAutoParticipantIndex` 32).
const TARGET_INDICES: u32 = 32;

/// The SPDP unicast port of participant `index` in `domain`.
pub fn spdp_port(domain: u16, index: u32) -> Option<u16> {
    u16::try_from(PB + DG * u32::from(domain) + D1 + PG * index).ok()
}

/// Whether `datagram` is an RTPS message from the participant with GUID prefix `prefix`.
pub fn from_participant(datagram: &[u8], prefix: &[u8; 12]) -> bool {
    datagram.len() >= 20 && &datagram[..4] == b"RTPS" && &datagram[8..20] == prefix
}

/// The destinations of our announcements on `ips`: each address's well-known ports.
pub fn destinations(domain: u16, ips: &BTreeSet<IpAddr>) -> Vec<SocketAddr> {
    ips.iter()
        .flat_map(|ip| {
            (0..TARGET_INDICES).filter_map(move |i| spdp_port(domain, i).map(|p| (*ip, p).into()))
        })
        .collect()
}

/// The host's own addresses other than loopback (IPv4, interfaces that are up).
pub fn host_addresses() -> Vec<IpAddr> {
    netdev::get_interfaces()
        .into_iter()
        .filter(|i| i.is_up() && !i.is_loopback())
        .flat_map(|i| i.ipv4.into_iter().map(|n| IpAddr::V4(n.addr())))
        .collect()
}

/// The relay's socket, bound before the participant starts (so that its first announcement
/// is kept).
pub struct RelaySocket {
    sock: UdpSocket,
    domain: u16,
}

/// A running relay; stops when dropped.
pub struct SpdpRelay {
    stop: Arc<AtomicBool>,
}

impl Drop for SpdpRelay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl RelaySocket {
    /// Binds 127.0.0.1 at the highest free well-known port RustDDS announces itself to.
    pub fn bind(domain: u16) -> Result<Self> {
        (1..RUSTDDS_LOCAL_PEERS)
            .rev()
            .filter_map(|i| spdp_port(domain, i))
            .find_map(|p| UdpSocket::bind(("127.0.0.1", p)).ok())
            .map(|sock| Self { sock, domain })
            .ok_or_else(|| {
                anyhow!("discovery relay: every well-known port on 127.0.0.1 of domain {domain} is taken")
            })
    }

    /// Starts relaying the announcements of the participant `prefix` to `peers` and to the
    /// local addresses other participants announce themselves from.
    pub fn start(self, prefix: [u8; 12], peers: Vec<IpAddr>) -> Result<SpdpRelay> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        self.sock
            .set_read_timeout(Some(Duration::from_millis(200)))?;
        std::thread::Builder::new()
            .name("spdp-relay".into())
            .spawn(move || relay(&self, &prefix, peers.into_iter().collect(), &flag))?;
        Ok(SpdpRelay { stop })
    }
}

/// The relay's loop: keeps our last announcement and sends it to every target; a new local
/// address (another participant's announcement) gets it at once.
fn relay(r: &RelaySocket, prefix: &[u8; 12], mut ips: BTreeSet<IpAddr>, stop: &AtomicBool) {
    let mut buf = [0u8; 65_536];
    let mut ours: Option<Vec<u8>> = None;
    while !stop.load(Ordering::Relaxed) {
        let Ok((n, from)) = r.sock.recv_from(&mut buf) else {
            continue;
        };
        let d = &buf[..n];
        let to: Vec<SocketAddr> = if from_participant(d, prefix) {
            ours = Some(d.to_vec());
            destinations(r.domain, &ips)
        } else if d.starts_with(b"RTPS") && !from.ip().is_loopback() && ips.insert(from.ip()) {
            destinations(r.domain, &BTreeSet::from([from.ip()]))
        } else {
            Vec::new()
        };
        if let Some(msg) = &ours {
            for a in to {
                // A peer that is not there is no error of ours; announcements repeat.
                let _ = r.sock.send_to(msg, a);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn well_known_ports() {
        // RTPS 9.6.2.3: 7400 + 250 d + 10 + 2 i.
        assert_eq!(spdp_port(0, 0), Some(7410));
        assert_eq!(spdp_port(63, 1), Some(23162));
        assert_eq!(spdp_port(232, 31), Some(65472));
        assert_eq!(spdp_port(232, 70), None);
    }

    #[test]
    fn own_announcements_are_told_by_their_prefix() {
        let prefix = [7u8; 12];
        let mut d = b"RTPS\x02\x04\x01\x12".to_vec();
        d.extend_from_slice(&prefix);
        assert!(from_participant(&d, &prefix));
        assert!(!from_participant(&d, &[8u8; 12]));
        assert!(!from_participant(&d[..19], &prefix));
        d[0] = b'X';
        assert!(!from_participant(&d, &prefix));
    }

    #[test]
    fn destinations_cover_each_address() {
        let ips = BTreeSet::from([IpAddr::from([192, 0, 2, 2]), IpAddr::from([10, 0, 0, 1])]);
        let d = destinations(1, &ips);
        assert_eq!(d.len(), 2 * TARGET_INDICES as usize);
        assert!(d.contains(&SocketAddr::from(([192, 0, 2, 2], 7660))));
    }
}
