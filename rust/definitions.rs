//! lightemma's shared definitions (`docs/definitions.md`) that the kernels use: the step of an action,
//! the ego box and the heading rule. The binding exports them as `_core` constants; `lightemma.definitions`
//! re-exports them, and `tests/unit/package/test_definitions.py` checks that both languages and every kernel default agree.

/// Seconds between two actions, and between nuScenes keyframes (docs/definitions.md#integration).
pub const STEP_SECONDS: f64 = 0.5;

/// Length of the ego box along the heading, metres: ST-P3's and UniAD's box (the Renault Zoe is 4.084 m long).
pub const EGO_LENGTH: f64 = 4.084;

/// Width of the ego box across the heading, metres: ST-P3's and UniAD's box (the Zoe's 1.73 m plus their margin).
pub const EGO_WIDTH: f64 = 1.85;

/// nuScenes' `LIDAR_TOP` lies this far ahead of the rear axle, the `ego_pose` reference point, metres
/// (`calibrated_sensor`).
pub const LIDAR_AHEAD_OF_REAR_AXLE: f64 = 0.943713;

/// UniAD shifts its ego box this far forward of the LiDAR, metres.
pub const UNIAD_BOX_SHIFT: f64 = 0.5;

/// How far the ego box's centre lies ahead of the `ego_pose` reference point (the rear axle), metres: 1.443713.
pub const EGO_OFFSET: f64 = LIDAR_AHEAD_OF_REAR_AXLE + UNIAD_BOX_SHIFT;

/// A trajectory step shorter than this keeps the previous heading, metres (BEV-Planner's rule).
pub const MIN_STEP: f64 = 1.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ego_box_centre_is_the_lidar_plus_uniads_shift() {
        assert_eq!(EGO_OFFSET, 1.443713);
    }
}
