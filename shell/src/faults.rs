//! Fault injection on frame streams (`m2smap run --faults SEED`): the sensor glitches and stream errors a robot
//! meets, applied deterministically to a fraction of the frames. Rejected frames are reported with their reason
//! and the run goes on; the mapper's tracks must stay sane (no update moves a track more than d_max).

use serde::Serialize;

use crate::dataset::LoadedFrame;
use crate::dataset::Pose;

/// One injected fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fault {
    /// The frame never arrives.
    Dropped,
    /// The frame arrives twice (same timestamp).
    RepeatedTimestamp,
    /// A depth image of zeros (a dead sensor): the core must reject it.
    ZeroDepth,
    /// 5 % of the depth pixels at the largest raw value and 5 % at the smallest.
    ExtremeDepth,
    /// A camera pose with NaN translation: the core must reject it.
    NanPose,
    /// The instance masks of the frame five earlier.
    StaleMasks,
    /// The camera pose jumps by 1 m.
    PoseJump,
}

/// Every fault kind.
pub const FAULTS: [Fault; 7] = [
    Fault::Dropped,
    Fault::RepeatedTimestamp,
    Fault::ZeroDepth,
    Fault::ExtremeDepth,
    Fault::NanPose,
    Fault::StaleMasks,
    Fault::PoseJump,
];

/// The fault of frame `k` under `seed`, hitting about `rate` of the frames (frame 0 is always clean).
pub fn fault_of(seed: u32, k: usize, rate: f32) -> Option<Fault> {
    use m2smap_core::points::mix32;
    let h = mix32(mix32(seed) ^ k as u32);
    let hit = (h as f64 / 4_294_967_296.0) < rate as f64;
    (k > 0 && hit).then(|| FAULTS[(mix32(h) % FAULTS.len() as u32) as usize])
}

/// Applies a depth fault to a decoded frame.
pub fn corrupt_depth(frame: &mut LoadedFrame, fault: Fault, seed: u32) {
    match fault {
        Fault::ZeroDepth => frame.depth.fill(0),
        Fault::ExtremeDepth => {
            for (i, d) in frame.depth.iter_mut().enumerate() {
                let h = m2smap_core::points::mix32(seed ^ (i as u32).wrapping_mul(2_654_435_761)) % 100;
                if h < 5 {
                    *d = u16::MAX;
                } else if h < 10 {
                    *d = 1;
                }
            }
        }
        _ => {}
    }
}

/// Applies a pose fault.
pub fn corrupt_pose(pose: Option<Pose>, fault: Fault) -> Option<Pose> {
    match (pose, fault) {
        (Some(p), Fault::NanPose) => Some(Pose { t: [f64::NAN, p.t[1], p.t[2]], ..p }),
        (None, Fault::NanPose) => Some(Pose { t: [f64::NAN, 0.0, 0.0], q: [0.0, 0.0, 0.0, 1.0] }),
        (Some(p), Fault::PoseJump) => Some(Pose { t: [p.t[0] + 1.0, p.t[1], p.t[2]], ..p }),
        (p, _) => p,
    }
}
