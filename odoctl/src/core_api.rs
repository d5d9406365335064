//! The parts of the hardware-free core (`odo_core`) that the tool uses: the tool never
//! reimplements the odometry, the uncertainty or the protocol.

pub use odo_core::odometry::trig;
pub use odo_core::odometry::{
    ChassisParams, IndexRefs, Integrator, ParamError, Pose, PoseSigma, PoseStep, StepStatus,
    UncertaintyModel, WheelCounts,
};
