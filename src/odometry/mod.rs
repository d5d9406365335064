//! Odometry: encoder arithmetic (eq 1), index-pulse (wheel angle) tracking, wheel distance
//! (eqs 3-6), pose (eqs 7-15) and uncertainty (eqs 19-28).

pub mod params;

pub use params::{
    ChassisParams, GeometryUncertainty, ParamError, UncertaintyModel, WheelHarmonics,
    WHEEL_HARMONICS,
};
pub mod encoder;
pub mod index;
pub mod integrator;
pub mod trig;
pub mod uncertainty;
pub mod wheel;

pub use encoder::CounterExtender;
pub use index::{extend_near, IndexCheck, IndexTracker};
pub use integrator::{
    IndexRefs, Integrator, Pose, PoseRangeError, PoseStep, StepStatus, WheelCounts,
};
pub use uncertainty::{PoseSigma, PoseUncertainty};
