//! Bindings of the planning score's simulation and comfort kernels (`rust/planning/simulate.rs`,
//! `rust/planning/comfort.rs`). NumPy in, NumPy out; the GIL is released for large batches.

use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::{array_nd, maybe_detach, view_nd};
use crate::planning::comfort as comfort_k;
use crate::planning::simulate as sim;

/// simulate(poses (N, K, 3), initial (N, 11), plan_dt, dt, vehicle (wheel_base, rear_axle_to_center,
/// max_steering_angle, accel_time_constant, steering_angle_time_constant)) -> (N, T+1, 11)
#[pyfunction]
#[pyo3(signature = (poses, initial, plan_dt = 0.5, dt = 0.1, vehicle = (2.588, 1.444, std::f64::consts::FRAC_PI_3, 0.2, 0.05)))]
fn simulate<'py>(
    py: Python<'py>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    initial: PyReadonlyArrayDyn<'py, f64>,
    plan_dt: f64,
    dt: f64,
    vehicle: (f64, f64, f64, f64, f64),
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (p, ps) = view_nd(&poses, "poses", 3, &[3], "(N, K, 3)")?;
    let (s, ss) = view_nd(&initial, "initial_state", 2, &[sim::STATE_SIZE], "(N, 11)")?;
    if ss[0] != ps[0] {
        return Err(crate::error::CoreError::Shape(format!(
            "initial_state has {} rows but poses has {} frames",
            ss[0], ps[0]
        ))
        .into());
    }
    let vehicle = sim::Vehicle {
        wheel_base: vehicle.0,
        rear_axle_to_center: vehicle.1,
        max_steering_angle: vehicle.2,
        accel_time_constant: vehicle.3,
        steering_angle_time_constant: vehicle.4,
    };
    let (n, k) = (ps[0], ps[1]);
    let steps = sim::resampled_steps(k.max(1), plan_dt, dt)?;
    let tracker = sim::Tracker::default();
    let out = maybe_detach(py, n, || {
        sim::simulate(p, s, k, plan_dt, dt, &vehicle, &tracker)
    })?;
    Ok(array_nd(out, &[n, steps + 1, sim::STATE_SIZE])?.into_pyarray(py))
}

/// What `comfort` returns: bounds met (N, 6) and signal extremes (N, 6, 2).
type ComfortArrays<'py> = (Bound<'py, PyArrayDyn<bool>>, Bound<'py, PyArrayDyn<f64>>);

/// comfort(states (N, T, 11), dt, rear_axle_to_center, history (N, H, 11) or None)
///     -> (within (N, 6) bool, extremes (N, 6, 2) min, max)
#[pyfunction]
#[pyo3(signature = (states, dt = 0.1, rear_axle_to_center = 1.444, history = None))]
fn comfort<'py>(
    py: Python<'py>,
    states: PyReadonlyArrayDyn<'py, f64>,
    dt: f64,
    rear_axle_to_center: f64,
    history: Option<PyReadonlyArrayDyn<'py, f64>>,
) -> PyResult<ComfortArrays<'py>> {
    let (s, shape) = view_nd(&states, "states", 3, &[sim::STATE_SIZE], "(N, T, 11)")?;
    let (n, t) = (shape[0], shape[1]);
    let (h, h_steps): (&[f64], usize) = match &history {
        Some(array) => {
            let (h, hs) = view_nd(array, "history", 3, &[sim::STATE_SIZE], "(N, H, 11)")?;
            if hs[0] != n {
                return Err(crate::error::CoreError::Shape(format!(
                    "history has {} frames but states has {n}",
                    hs[0]
                ))
                .into());
            }
            (h, hs[1])
        }
        None => (&[], 0),
    };
    let out = maybe_detach(py, n, || {
        comfort_k::comfort(s, t, h, h_steps, dt, rear_axle_to_center)
    })?;
    let within: Vec<bool> = out.iter().flat_map(|c| c.within).collect();
    let extremes: Vec<f64> = out
        .iter()
        .flat_map(|c| c.extremes.iter().flat_map(|(lo, hi)| [*lo, *hi]))
        .collect();
    Ok((
        array_nd(within, &[n, 6])?.into_pyarray(py),
        array_nd(extremes, &[n, 6, 2])?.into_pyarray(py),
    ))
}

/// extended_comfort(now (N, T, 11), prev (N, T, 11), dt, shift) -> RMS differences (N, 4)
#[pyfunction]
#[pyo3(signature = (now, prev, dt = 0.1, shift = 5))]
fn extended_comfort<'py>(
    py: Python<'py>,
    now: PyReadonlyArrayDyn<'py, f64>,
    prev: PyReadonlyArrayDyn<'py, f64>,
    dt: f64,
    shift: usize,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let (a, sa) = view_nd(&now, "states_now", 3, &[sim::STATE_SIZE], "(N, T, 11)")?;
    let (b, sb) = view_nd(&prev, "states_prev", 3, &[sim::STATE_SIZE], "(N, T, 11)")?;
    if sa != sb {
        return Err(crate::error::CoreError::Shape(format!(
            "states_prev must have the shape of states_now: {sb:?} against {sa:?}"
        ))
        .into());
    }
    let (n, t) = (sa[0], sa[1]);
    let out = maybe_detach(py, n, || comfort_k::extended_comfort(a, b, t, dt, shift))?;
    let flat: Vec<f64> = out.into_iter().flatten().collect();
    Ok(array_nd(flat, &[n, 4])?.into_pyarray(py))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(comfort, m)?)?;
    m.add_function(wrap_pyfunction!(extended_comfort, m)?)?;
    m.add(
        "ZOE_REAR_AXLE_TO_CENTER",
        sim::Vehicle::ZOE.rear_axle_to_center,
    )?;
    m.add("COMFORT_BOUNDS", comfort_k::BOUND_NAMES.to_vec())?;
    m.add("COMFORT_LIMITS", comfort_k::BOUNDS.to_vec())?;
    m.add(
        "EXTENDED_COMFORT_FEATURES",
        comfort_k::EXTENDED_NAMES.to_vec(),
    )?;
    m.add(
        "EXTENDED_COMFORT_LIMITS",
        comfort_k::EXTENDED_LIMITS.to_vec(),
    )?;
    Ok(())
}
