//! NAVSIM's planning score on nuScenes: re-simulation of a plan and its sub-scores.
//!
//! * [`simulate`]: a plan's poses, resampled at 0.1 s, tracked by an LQR controller on a kinematic
//!   bicycle model from the frame's initial ego state (NAVSIM's `pdm_simulator.py`, `batch_lqr.py`,
//!   `batch_kinematic_bicycle.py`), giving states in NAVSIM's 11-column layout;
//! * [`comfort`]: nuPlan's comfort bounds on simulated states (history comfort `hc`, v1 comfort `c`)
//!   and the two-frame extended comfort `ec` (NAVSIM's `pdm_comfort_metrics.py`);
//! * [`scores`]: the per-frame sub-scores on simulated states (`nc`, `dac`, `ddc`, `ep`, `ttc`, `lk`)
//!   and the aggregates `pdms`, `epdms`, `epdms_map` (NAVSIM's `pdm_scorer.py`).
//!
//! Definitions, sources and every deviation from NAVSIM: `docs/definitions.md#planning-score`.

pub mod comfort;
pub mod scores;
pub mod simulate;
