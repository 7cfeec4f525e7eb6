//! lightemma's numeric and text kernels.
//!
//! * [`parse`] (its modules [`parse::lexer`], [`parse::lenient`], [`parse::paper`], [`parse::json`]): a model's
//!   stage-3 answer → (speed, curvature) actions, a status, a failure kind and a reason;
//! * [`intent`]: a stage-2 text → the stated longitudinal and lateral intent (`intent@lightemma/1`);
//! * [`objects`]: a stage-1 text → the object classes it mentions, negates or hedges (`objects@lightemma/1`);
//! * [`kinematics`]: actions → trajectories (`euler`, `midpoint`), batched;
//! * [`metrics`]: per-step displacement errors, ADE/FDE under three conventions, miss rate;
//! * [`safety`]: the ego footprint along a trajectory (SE(2), nalgebra), exact rotated-rectangle
//!   collisions with agents' boxes, drivable-area tests against a raster mask or polygons;
//! * [`planning`]: NAVSIM's planning score on nuScenes (re-simulation, comfort, sub-scores);
//! * [`stats`]: scene-level bootstrap intervals and sign-flip p-values (deterministic, parallel);
//! * [`definitions`]: the step seconds and the ego box every kernel defaults to (`lightemma.definitions`);
//! * [`error`]: the one error type, mapped to lightemma's exception classes (`ValueError` subclasses) in
//!   `python/errors.rs`.
//!
//! Everything but `python.rs` is plain Rust, tested with `cargo test` without Python.

pub mod definitions;
pub mod error;
pub mod fastmath;
pub mod intent;
pub mod kinematics;
pub mod metrics;
pub mod objects;
pub mod parse;
pub mod planning;
mod python;
pub mod safety;
pub mod stats;
