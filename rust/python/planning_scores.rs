//! Bindings of the planning score's sub-score kernels (`rust/planning/scores.rs`).

use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::safety::mask_of;
use super::{array_nd, offsets_of, slice1, view_nd};
use crate::error::CoreError;
use crate::planning::scores::{self, Config, Inputs, Lanes, Layer};
use crate::safety::EgoShape;

/// What `planning_subscores` returns: values (N, 6) and reason codes (N, 6).
type Scored<'py> = (Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<u8>>);

/// A polygon set as Python passes it: vertices (V, 2), ring offsets (R + 1,), polygon offsets (P + 1,).
type PolygonArrays<'py> = (
    PyReadonlyArrayDyn<'py, f64>,
    PyReadonlyArray1<'py, i64>,
    PyReadonlyArray1<'py, i64>,
);

/// Borrowed vertices and owned offsets of a polygon set.
struct PolygonSet<'a> {
    xy: &'a [f64],
    rings: Vec<usize>,
    polygons: Vec<usize>,
}

fn polygon_set<'a>(p: &'a PolygonArrays<'_>, name: &str) -> PyResult<PolygonSet<'a>> {
    let (xy, _) = view_nd(&p.0, &format!("{name} vertices"), 2, &[2], "(V, 2)")?;
    Ok(PolygonSet {
        xy,
        rings: offsets_of(&p.1)?,
        polygons: offsets_of(&p.2)?,
    })
}

/// A per-frame polyline array (F, R, 2): (data, F, R).
fn lines<'a>(
    a: &'a Option<PyReadonlyArrayDyn<'_, f64>>,
    name: &str,
) -> PyResult<Option<(&'a [f64], usize, usize)>> {
    a.as_ref()
        .map(|a| {
            let (d, s) = view_nd(a, name, 3, &[2], "(F, R, 2)")?;
            Ok((d, s[0], s[1]))
        })
        .transpose()
}

/// planning_subscores(states (N, S, 11), frame (N,), …) -> (values (N, 6) float64, codes (N, 6) uint8)
#[pyfunction]
#[pyo3(signature = (
    states, frame, *, agents = None, drivable_mask = None, mask_resolution = 0.1, mask_foreground = 255,
    drivable = None, lanes = None, lane_offsets = None, lane_ids = None, lane_on_route = None,
    intersections = None, route = None, centreline = None, n_frames = None,
    length = 4.084, width = 1.85, rear_axle_to_center = 1.444, dt = 0.1
))]
#[allow(clippy::too_many_arguments)]
fn planning_subscores<'py>(
    py: Python<'py>,
    states: PyReadonlyArrayDyn<'py, f64>,
    frame: PyReadonlyArray1<'py, i64>,
    agents: Option<PyReadonlyArrayDyn<'py, f64>>,
    drivable_mask: Option<PyReadonlyArrayDyn<'py, u8>>,
    mask_resolution: f64,
    mask_foreground: u8,
    drivable: Option<PolygonArrays<'py>>,
    lanes: Option<PolygonArrays<'py>>,
    lane_offsets: Option<PyReadonlyArray1<'py, i64>>,
    lane_ids: Option<PyReadonlyArray1<'py, i64>>,
    lane_on_route: Option<PyReadonlyArray1<'py, u8>>,
    intersections: Option<PolygonArrays<'py>>,
    route: Option<PyReadonlyArrayDyn<'py, f64>>,
    centreline: Option<PyReadonlyArrayDyn<'py, f64>>,
    n_frames: Option<usize>,
    length: f64,
    width: f64,
    rear_axle_to_center: f64,
    dt: f64,
) -> PyResult<Scored<'py>> {
    let (st, sshape) = view_nd(&states, "states", 3, &[scores::STATE_SIZE], "(N, S, 11)")?;
    let (n, steps) = (sshape[0], sshape[1]);
    let frame: Vec<usize> = slice1(&frame, "frame")?
        .iter()
        .map(|&f| {
            usize::try_from(f)
                .map_err(|_| super::errors::argument(format!("frame indices must be ≥ 0, got {f}")))
        })
        .collect::<PyResult<_>>()?;

    // F: every per-frame input must agree on it
    let agents_v = agents
        .as_ref()
        .map(|a| view_nd(a, "agents", 4, &[scores::AGENT_VALUES], "(F, S, A, 8)"))
        .transpose()?;
    let route_v = lines(&route, "route")?;
    let centre_v = lines(&centreline, "centreline")?;
    let lane_off = lane_offsets.as_ref().map(offsets_of).transpose()?;
    let mut sizes: Vec<(&str, usize)> = Vec::new();
    if let Some((_, s)) = &agents_v {
        sizes.push(("agents", s[0]));
        if s[1] != steps {
            return Err(CoreError::Shape(format!(
                "agents have {} steps but states have {steps}",
                s[1]
            ))
            .into());
        }
    }
    if let Some((_, f, _)) = route_v {
        sizes.push(("route", f));
    }
    if let Some((_, f, _)) = centre_v {
        sizes.push(("centreline", f));
    }
    if let Some(o) = &lane_off {
        sizes.push(("lane_offsets", o.len().saturating_sub(1)));
    }
    if let Some(f) = n_frames {
        sizes.push(("n_frames", f));
    }
    let frames = match sizes.first() {
        Some(&(_, f)) => {
            if let Some((name, g)) = sizes.iter().find(|(_, g)| *g != f) {
                return Err(CoreError::Shape(format!(
                    "per-frame inputs disagree on the number of frames: {} has {f}, {name} has {g}",
                    sizes[0].0
                ))
                .into());
            }
            f
        }
        None => frame.iter().max().map_or(0, |m| m + 1),
    };

    let drivable_set = drivable
        .as_ref()
        .map(|p| polygon_set(p, "drivable"))
        .transpose()?;
    let inter_set = intersections
        .as_ref()
        .map(|p| polygon_set(p, "intersections"))
        .transpose()?;
    let lane_set = lanes
        .as_ref()
        .map(|p| polygon_set(p, "lanes"))
        .transpose()?;
    let parts_of = |set: &Option<PolygonSet<'_>>| {
        set.as_ref()
            .map(|s| scores::polygon_parts(&s.rings, &s.polygons))
            .transpose()
    };
    let (drivable_parts, inter_parts) = (parts_of(&drivable_set)?, parts_of(&inter_set)?);
    let drivable_layer = match (&drivable_mask, &drivable_set, &drivable_parts) {
        (Some(_), Some(_), _) => {
            return Err(super::errors::argument(
                "give the drivable area as a mask or as polygons, not both",
            ))
        }
        (Some(m), None, _) => Some(Layer::Mask(mask_of(m, mask_resolution, mask_foreground)?)),
        (None, Some(s), Some(parts)) => Some(Layer::polygons(s.xy, parts)?),
        _ => None,
    };
    let inter_layer = match (&inter_set, &inter_parts) {
        (Some(s), Some(parts)) => Some(Layer::polygons(s.xy, parts)?),
        _ => None,
    };
    let lane_ids_v: Option<Vec<usize>> = lane_ids.as_ref().map(offsets_of).transpose()?;
    let parts = parts_of(&lane_set)?;
    let lanes_v = match (&lane_set, &parts, &lane_off, &lane_ids_v, &lane_on_route) {
        (None, ..) => None,
        (Some(s), Some(parts), Some(off), Some(ids), Some(on)) => Some(Lanes {
            polygons: scores::single_polygons(s.xy, parts)?,
            offsets: off,
            ids,
            on_route: slice1(on, "lane_on_route")?,
        }),
        _ => {
            return Err(super::errors::argument(
                "lanes need lane_offsets, lane_ids and lane_on_route",
            ))
        }
    };
    let inp = Inputs {
        states: st,
        steps,
        frame: &frame,
        frames,
        agents: agents_v.as_ref().map(|(a, s)| (*a, s[2])),
        drivable: drivable_layer.as_ref(),
        lanes: lanes_v.as_ref(),
        intersections: inter_layer.as_ref(),
        route: route_v.map(|(d, _, r)| (d, r)),
        centreline: centre_v.map(|(d, _, r)| (d, r)),
        shape: EgoShape {
            length,
            width,
            offset: rear_axle_to_center,
            min_step: 0.0,
        },
        config: Config {
            dt,
            ..Config::default()
        },
    };
    let (values, codes) = super::maybe_detach(py, n, || scores::subscores(&inp))?;
    Ok((
        array_nd(values, &[n, scores::SCORES])?.into_pyarray(py),
        array_nd(codes, &[n, scores::SCORES])?.into_pyarray(py),
    ))
}

/// first_bad_box(agents (F, S, A, 8), frame) -> (step, slot) of the first degenerate box of that frame, or None
#[pyfunction]
fn planning_first_bad_box(
    agents: PyReadonlyArrayDyn<'_, f64>,
    frame: usize,
) -> PyResult<Option<(usize, usize)>> {
    let (a, s) = view_nd(
        &agents,
        "agents",
        4,
        &[scores::AGENT_VALUES],
        "(F, S, A, 8)",
    )?;
    if frame >= s[0] {
        return Err(super::errors::argument(format!(
            "frame {frame} is out of range for {} frames",
            s[0]
        )));
    }
    Ok(scores::first_bad_box(a, s[2], s[1], frame))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(planning_subscores, m)?)?;
    m.add_function(wrap_pyfunction!(planning_first_bad_box, m)?)?;
    m.add("PLANNING_SCORE_NAMES", scores::SCORE_NAMES.to_vec())?;
    m.add("PLANNING_REASONS", scores::REASON_NAMES.to_vec())?;
    Ok(())
}
