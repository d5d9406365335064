//! `reset_pose` as a ROS 2 service of the bridge: `std_srvs/srv/Trigger` on
//! `<namespace>/reset_pose` (DDS topics `rq/<ns>/reset_poseRequest`, `rr/<ns>/reset_poseReply`,
//! the request header in the payload as rmw_cyclonedds writes it). A request sends
//! `reset_pose` to the unit and is answered with the unit's reply (`success` = the unit said
//! `ok`); one reset at a time, the others wait in order. docs/ROS.md, *Reset from ROS*.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Message, Name, Node, QosProfile, RmwRequestId, Server, ServiceMapping, ServiceTypeName,
};
use serde::{Deserialize, Serialize};

use super::names::RosNames;

/// `std_srvs/srv/Trigger` request (no fields; the member IDL needs).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerRequest {
    /// Always 0.
    pub structure_needs_at_least_one_member: u8,
}
impl Message for TriggerRequest {}

/// `std_srvs/srv/Trigger` response.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerResponse {
    /// The unit confirmed the reset (`ok`).
    pub success: bool,
    /// The unit's reply, or why there is none.
    pub message: String,
}
impl Message for TriggerResponse {}

/// The request being served: its id, when `reset_pose` was sent, the reply so far.
struct Pending {
    id: RmwRequestId,
    sent: Instant,
    text: String,
}

/// The service: requests waiting, the one sent to the unit.
pub struct ResetService {
    server: Server<TriggerRequest, TriggerResponse>,
    waiting: VecDeque<RmwRequestId>,
    pending: Option<Pending>,
    answered: u64,
}

/// How long the unit has to reply to `reset_pose`.
pub const RESET_TIMEOUT: Duration = Duration::from_secs(5);

impl ResetService {
    /// The server of `names.reset_service` on `node`: reliable, volatile, keep last 10 (ROS
    /// 2's service default).
    pub fn new(node: &mut Node, names: &RosNames) -> Result<Self> {
        let (ns, base) = RosNames::split(&names.reset_service);
        let name = Name::new(ns, base).map_err(|e| anyhow!("DDS: service name: {e:?}"))?;
        let qos = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 10 });
        let server = node
            .create_server(
                ServiceMapping::Cyclone,
                &name,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                qos.clone(),
                qos,
            )
            .map_err(|e| anyhow!("DDS: service {}: {e:?}", names.reset_service))?;
        Ok(Self {
            server,
            waiting: VecDeque::new(),
            pending: None,
            answered: 0,
        })
    }

    /// Requests answered so far.
    pub fn answered(&self) -> u64 {
        self.answered
    }

    /// Takes new requests; `true` when one becomes the pending one, and `reset_pose` must be
    /// sent to the unit now.
    pub fn poll(&mut self) -> bool {
        while let Ok(Some((id, _))) = self.server.receive_request() {
            self.waiting.push_back(id);
        }
        if self.pending.is_none() {
            if let Some(id) = self.waiting.pop_front() {
                self.pending = Some(Pending {
                    id,
                    sent: Instant::now(),
                    text: String::new(),
                });
                return true;
            }
        }
        false
    }

    /// A reply frame from the unit: completes the pending request when it is the last frame
    /// of the reply; `true` when the unit confirmed the reset (its next record carries it).
    pub fn reply(&mut self, ok: bool, text: &str, more: bool) -> bool {
        let Some(p) = &mut self.pending else {
            return false;
        };
        p.text.push_str(text);
        if !more {
            let message = match (p.text.trim(), ok) {
                ("", true) => "unit: ok".to_string(),
                ("", false) => "unit: error".to_string(),
                (t, _) => format!("unit: {t}"),
            };
            self.answer(ok, message);
            return ok;
        }
        false
    }

    /// Answers the pending request as failed when the unit did not reply within
    /// [`RESET_TIMEOUT`].
    pub fn expire(&mut self) {
        if self
            .pending
            .as_ref()
            .is_some_and(|p| p.sent.elapsed() > RESET_TIMEOUT)
        {
            let msg = format!(
                "no reply from the unit within {} s",
                RESET_TIMEOUT.as_secs()
            );
            self.answer(false, msg);
        }
    }

    /// Answers the pending and the waiting requests as failed: `why` (no link to the unit).
    pub fn fail_all(&mut self, why: &str) {
        while let Ok(Some((id, _))) = self.server.receive_request() {
            self.waiting.push_back(id);
        }
        if self.pending.is_some() {
            self.answer(false, why.to_string());
        }
        while let Some(id) = self.waiting.pop_front() {
            self.send(id, false, why.to_string());
        }
    }

    fn answer(&mut self, success: bool, message: String) {
        if let Some(p) = self.pending.take() {
            self.send(p.id, success, message);
        }
    }

    fn send(&mut self, id: RmwRequestId, success: bool, message: String) {
        self.answered += 1;
        // A client that left does not stop the bridge; it is counted as answered.
        if let Err(e) = self
            .server
            .send_response(id, TriggerResponse { success, message })
        {
            eprintln!("bridge: reset_pose response not sent: {e:?}");
        }
    }
}
