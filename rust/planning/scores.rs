//! NAVSIM's per-frame sub-scores on simulated ego states (docs/definitions.md#sub-scores-and-aggregates).
//!
//! Source: `autonomousvision/navsim`, `pdm_scorer.py` (`_calculate_ego_area`, `_calculate_no_at_fault_collision`,
//! `_calculate_drivable_area_compliance`, `_calculate_driving_direction_compliance`, `_calculate_progress`,
//! `_calculate_ttc`, `_calculate_lane_keeping`), `pdm_scorer_utils.py` (`get_collision_type`) and nuPlan's
//! `is_agent_ahead` / `is_agent_behind` / `is_track_stopped`; thresholds from `pdm_scorer.yaml`.
//!
//! Inputs are generic geometry in the global (map) frame, metres, radians, seconds:
//! * `states` (N·S·11): NAVSIM's `StateIndex` layout (x, y, heading, velocity x, velocity y, …) of the rear
//!   axle, S = T + 1 steps `dt` apart (the initial state first);
//! * `frame` (N): which scene frame (0..F) each plan belongs to — the per-frame inputs below are shared by
//!   every plan of that frame (the models of a study);
//! * agents (F·S·A·8): per frame, step and track slot: centre x, y, yaw, length, width, velocity x, y and a
//!   kind (0 a moving-capable agent — vehicle, pedestrian, bicycle —, 1 a static object); a slot is the same
//!   track at every step; a NaN centre x is an absent track;
//! * the drivable area ([`Layer`]: a mask or polygons), lane polygons with per-frame candidate lists and
//!   on-route flags ([`Lanes`]), intersection polygons, and per-frame polylines (F·R·2, NaN rows as
//!   trailing padding): the route for progress, the centreline for lane keeping.
//!
//! Per frame and sub-score the kernel returns a value or NaN with a reason code ([`OK`], [`BAD_STATES`], …):
//! nothing it cannot decide is ever a silent 0 or 1.

use nalgebra::{Point2, Vector2};
use rayon::prelude::*;

use crate::error::{CoreError, CoreResult};
use crate::safety::{self, EgoShape, Mask, PolygonIndex, Polygons, Rect, ON};

/// Values per simulated state (NAVSIM's `StateIndex`).
pub const STATE_SIZE: usize = 11;
const X: usize = 0;
const Y: usize = 1;
const HEADING: usize = 2;
const VX: usize = 3;
const VY: usize = 4;

/// Values per agent box: centre x, y, yaw, length, width, velocity x, y, kind.
pub const AGENT_VALUES: usize = 8;
/// `kind` of an agent (nuPlan's `AGENT_TYPES`: vehicle, pedestrian, bicycle): an at-fault collision scores 0.
pub const KIND_AGENT: f64 = 0.0;
/// `kind` of a static object (barrier, cone, …): always "stopped"; an at-fault collision scores 0.5.
pub const KIND_OBJECT: f64 = 1.0;

/// Sub-score columns of the output.
pub const NC: usize = 0;
pub const DAC: usize = 1;
pub const DDC: usize = 2;
/// Raw ego progress along the route, metres, clipped at 0 (normalised by the aggregation).
pub const EP: usize = 3;
pub const TTC: usize = 4;
pub const LK: usize = 5;
/// Number of sub-score columns.
pub const SCORES: usize = 6;
/// Column names, in order.
pub const SCORE_NAMES: [&str; SCORES] = ["nc", "dac", "ddc", "ep_raw", "ttc", "lk"];

/// Reason codes (one per frame and sub-score).
pub const OK: u8 = 0;
/// The plan's states hold a NaN or infinity.
pub const BAD_STATES: u8 = 1;
/// No agents' boxes were given (a version without annotations).
pub const NO_AGENTS: u8 = 2;
/// One of the frame's boxes is degenerate (non-finite value, size ≤ 0, unknown kind).
pub const BAD_BOX: u8 = 3;
/// No drivable area was given.
pub const NO_DRIVABLE: u8 = 4;
/// No lane polygons were given.
pub const NO_LANES: u8 = 5;
/// No intersection polygons were given.
pub const NO_INTERSECTIONS: u8 = 6;
/// A collision's at-fault class (or a TTC event's) depends on a map layer that was not given.
pub const UNDETERMINED: u8 = 7;
/// The frame's route has fewer than two finite points, or a non-finite point before its padding.
pub const NO_ROUTE: u8 = 8;
/// The frame's centreline has fewer than two finite points, or a non-finite point before its padding.
pub const NO_CENTRELINE: u8 = 9;
/// The frame's lane list has no on-route lane (every step would count as oncoming).
pub const NO_ROUTE_LANES: u8 = 10;
/// Reason code names, indexed by code.
pub const REASON_NAMES: [&str; 11] = [
    "ok",
    "bad_states",
    "no_agents",
    "bad_box",
    "no_drivable",
    "no_lanes",
    "no_intersections",
    "undetermined",
    "no_route",
    "no_centreline",
    "no_route_lanes",
];

/// NAVSIM's thresholds (`PDMScorerConfig`, `get_collision_type`, nuPlan's IDM utilities).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    /// Step between states, s (NAVSIM: 0.1).
    pub dt: f64,
    /// Ego or track at or below this speed is stopped for the collision class, m/s (`get_collision_type`: 0.05).
    pub collision_stopped_speed: f64,
    /// Ego below this speed is not checked for TTC, m/s (`stopped_speed_threshold`: 0.005).
    pub ttc_stopped_speed: f64,
    /// TTC looks this far ahead, s (`future_collision_horizon_window`: 1.0), every `ttc_stride` steps (3).
    pub ttc_horizon: f64,
    pub ttc_stride: usize,
    /// DDC window, s (`driving_direction_horizon`: 1.0), and thresholds, m (2.0, 6.0).
    pub ddc_horizon: f64,
    pub ddc_compliance: f64,
    pub ddc_violation: f64,
    /// LK: deviation limit, m (0.5), and how long it must last, s (2.0).
    pub lk_limit: f64,
    pub lk_window: f64,
    /// nuPlan's `is_agent_ahead` (30°) and `is_agent_behind` (150°) tolerances, radians.
    pub ahead: f64,
    pub behind: f64,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            dt: 0.1,
            collision_stopped_speed: 5e-2,
            ttc_stopped_speed: 5e-3,
            ttc_horizon: 1.0,
            ttc_stride: 3,
            ddc_horizon: 1.0,
            ddc_compliance: 2.0,
            ddc_violation: 6.0,
            lk_limit: 0.5,
            lk_window: 2.0,
            ahead: 30f64.to_radians(),
            behind: 150f64.to_radians(),
        }
    }
}

impl Config {
    pub fn check(&self) -> CoreResult<()> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !pos(self.dt) || self.ttc_stride == 0 {
            return Err(CoreError::Argument(format!(
                "dt must be positive and finite, got {}",
                self.dt
            )));
        }
        Ok(())
    }

    /// NAVSIM's `np.arange(0, int(horizon · 10), 3)` with 10 = 1 / dt: the TTC projection steps.
    pub fn ttc_steps(&self) -> Vec<usize> {
        let end = (self.ttc_horizon / self.dt + 1e-9).floor() as usize;
        (0..end).step_by(self.ttc_stride).collect()
    }

    /// `int(driving_direction_horizon / interval_length)`.
    pub fn ddc_steps(&self) -> usize {
        (self.ddc_horizon / self.dt + 1e-9).floor() as usize
    }

    /// `int(np.ceil(lane_keeping_horizon_window / interval_length))`.
    pub fn lk_steps(&self) -> usize {
        (self.lk_window / self.dt - 1e-9).ceil().max(1.0) as usize
    }
}

/// Lane polygons of a map with per-frame candidate lists: frame f's lanes are
/// `ids[offsets[f]..offsets[f + 1]]`, each with an on-route flag (1: a lane of the route the ground
/// truth drives).
pub struct Lanes<'a> {
    pub polygons: Vec<PolygonIndex<'a>>,
    pub offsets: &'a [usize],
    pub ids: &'a [usize],
    pub on_route: &'a [u8],
}

/// Per-polygon ring offsets rebased to the polygon's own vertices, so that each polygon of a set can be
/// indexed alone ([`single_polygons`]): (first vertex, last vertex + 1, ring offsets, [0, rings]).
pub type PolygonParts = Vec<(usize, usize, Vec<usize>, [usize; 2])>;

/// Split a polygon set (vertex offsets `rings`, ring offsets `polygons`) into its polygons.
pub fn polygon_parts(rings: &[usize], polygons: &[usize]) -> CoreResult<PolygonParts> {
    let mut out = Vec::with_capacity(polygons.len().saturating_sub(1));
    for w in polygons.windows(2) {
        let (r0, r1) = (w[0], w[1]);
        if r0 > r1 || r1 >= rings.len() {
            return Err(CoreError::Shape(format!(
                "polygon ring offsets {r0}..{r1} do not fit {} ring offsets",
                rings.len()
            )));
        }
        let (v0, v1) = (rings[r0], rings[r1]);
        if rings[r0..=r1].windows(2).any(|p| p[0] > p[1]) {
            return Err(CoreError::Shape(
                "ring offsets must not decrease".to_owned(),
            ));
        }
        let rebased = rings[r0..=r1].iter().map(|r| r - v0).collect();
        out.push((v0, v1, rebased, [0, r1 - r0]));
    }
    Ok(out)
}

/// One [`PolygonIndex`] per polygon of `parts` (from [`polygon_parts`]) over the vertices `xy`.
pub fn single_polygons<'a>(
    xy: &'a [f64],
    parts: &'a PolygonParts,
) -> CoreResult<Vec<PolygonIndex<'a>>> {
    parts
        .iter()
        .map(|(v0, v1, rings, polys)| {
            if 2 * v1 > xy.len() {
                return Err(CoreError::Shape(format!(
                    "ring offsets reach vertex {v1} but xy has {} vertices",
                    xy.len() / 2
                )));
            }
            PolygonIndex::new(Polygons {
                xy: &xy[2 * v0..2 * v1],
                rings,
                polygons: polys,
            })
        })
        .collect()
}

/// A map layer: a devkit mask, or polygons indexed one by one with their bounding boxes (so that each frame
/// tests only the polygons near its plans).
pub enum Layer<'a> {
    Mask(Mask<'a>),
    Polygons {
        polygons: Vec<PolygonIndex<'a>>,
        bounds: Vec<[f64; 4]>,
    },
}

impl<'a> Layer<'a> {
    /// A polygon layer from vertices `xy` and [`polygon_parts`].
    pub fn polygons(xy: &'a [f64], parts: &'a PolygonParts) -> CoreResult<Self> {
        let polygons = single_polygons(xy, parts)?;
        let bounds = parts
            .iter()
            .map(|(v0, v1, _, _)| {
                xy[2 * v0..2 * v1].chunks_exact(2).fold(
                    [
                        f64::INFINITY,
                        f64::INFINITY,
                        f64::NEG_INFINITY,
                        f64::NEG_INFINITY,
                    ],
                    |b, p| {
                        [
                            b[0].min(p[0]),
                            b[1].min(p[1]),
                            b[2].max(p[0]),
                            b[3].max(p[1]),
                        ]
                    },
                )
            })
            .collect();
        Ok(Layer::Polygons { polygons, bounds })
    }

    /// The polygons whose bounding box meets the box `lo`–`hi` (all of them for a mask: none to list).
    fn near(&self, lo: [f64; 2], hi: [f64; 2]) -> Vec<usize> {
        match self {
            Layer::Mask(_) => Vec::new(),
            Layer::Polygons { bounds, .. } => (0..bounds.len())
                .filter(|&p| {
                    let b = bounds[p];
                    b[0] <= hi[0] && b[2] >= lo[0] && b[1] <= hi[1] && b[3] >= lo[1]
                })
                .collect(),
        }
    }

    /// Whether (x, y) is on the layer; `near` from [`Layer::near`] for a region holding the point. A mask
    /// pixel outside the image is not on it.
    fn contains(&self, near: &[usize], x: f64, y: f64) -> bool {
        let mut hint = usize::MAX;
        self.contains_from(near, x, y, &mut hint)
    }

    /// [`Layer::contains`], testing first the polygon `hint` (the one that held the previous point, when
    /// it is one of `near`) and leaving in it the polygon that holds this point. The answer is the same in
    /// any order (membership of the union); successive corners of a plan mostly lie in the same polygon.
    fn contains_from(&self, near: &[usize], x: f64, y: f64, hint: &mut usize) -> bool {
        match self {
            Layer::Mask(m) => m.lookup(x, y) == ON,
            Layer::Polygons { polygons, bounds } => {
                let holds = |p: usize| {
                    let b = bounds[p];
                    x >= b[0] && x <= b[2] && y >= b[1] && y <= b[3] && polygons[p].contains(x, y)
                };
                if *hint < polygons.len() && holds(*hint) {
                    return true;
                }
                match near.iter().find(|&&p| p != *hint && holds(p)) {
                    Some(&p) => {
                        *hint = p;
                        true
                    }
                    None => false,
                }
            }
        }
    }
}

/// A polyline (the route, the centreline) with each segment's squared length, length and the arc length at
/// its start, computed once per frame for every projection onto it ([`Line::project`]).
struct Line<'a> {
    xy: &'a [f64],
    /// Per segment: squared length, length, arc length at its first point (the running sum of the lengths
    /// before it, in order: the same sums as [`project`]'s).
    seg: Vec<[f64; 3]>,
}

impl<'a> Line<'a> {
    fn new(xy: &'a [f64]) -> Self {
        let mut walked = 0.0;
        let seg = (0..xy.len() / 2 - 1)
            .map(|i| {
                let d = Vector2::new(xy[2 * i + 2] - xy[2 * i], xy[2 * i + 3] - xy[2 * i + 1]);
                let len2 = d.norm_squared();
                let out = [len2, len2.sqrt(), walked];
                walked += len2.sqrt();
                out
            })
            .collect();
        Line { xy, seg }
    }

    /// [`project`], value for value: a segment is skipped only when its squared distance exceeds the best
    /// distance squared with a margin (so that its distance could not be smaller); the others are compared
    /// by the same distances as [`project`].
    fn project(&self, p: Point2<f64>) -> (f64, f64) {
        let (mut best, mut along) = (f64::INFINITY, 0.0);
        let mut bound = f64::INFINITY;
        let line = self.xy;
        for (i, sg) in self.seg.iter().enumerate() {
            let a = Point2::new(line[2 * i], line[2 * i + 1]);
            let d = Point2::new(line[2 * i + 2], line[2 * i + 3]) - a;
            let len2 = sg[0];
            let t = if len2 > 0.0 {
                ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let d2 = (a + d * t - p).norm_squared();
            if d2 > bound {
                continue;
            }
            let dist = d2.sqrt();
            if dist < best {
                best = dist;
                along = sg[2] + t * sg[1];
                bound = best * best * (1.0 + 1e-12);
            }
        }
        (best, along)
    }
}

/// The polygons of each layer near one frame's plans, and the frame's route and centreline.
struct Near<'a> {
    drivable: Vec<usize>,
    intersections: Vec<usize>,
    route: Option<Line<'a>>,
    centreline: Option<Line<'a>>,
}

/// The polygons that held the previous step's points, per layer ([`Layer::contains_from`]).
#[derive(Clone, Copy)]
struct Hints {
    drivable: usize,
    intersection: usize,
}

/// Everything the kernel reads. Optional inputs that are `None` make the sub-scores that need them n/a.
pub struct Inputs<'a> {
    pub states: &'a [f64],
    pub steps: usize,
    pub frame: &'a [usize],
    /// Number of scene frames F the per-frame inputs hold.
    pub frames: usize,
    pub agents: Option<(&'a [f64], usize)>,
    pub drivable: Option<&'a Layer<'a>>,
    pub lanes: Option<&'a Lanes<'a>>,
    pub intersections: Option<&'a Layer<'a>>,
    /// Polylines (F·R·2) and R.
    pub route: Option<(&'a [f64], usize)>,
    pub centreline: Option<(&'a [f64], usize)>,
    pub shape: EgoShape,
    pub config: Config,
}

/// Three-valued logic for map-dependent predicates: `Some(b)` known, `None` the layer is missing.
type Tri = Option<bool>;

fn tri_or(a: Tri, b: Tri) -> Tri {
    match (a, b) {
        (Some(true), _) | (_, Some(true)) => Some(true),
        (Some(false), Some(false)) => Some(false),
        _ => None,
    }
}

/// Where the ego is at one step (NAVSIM's `EgoAreaIndex`, plus intersections) as every step needs it;
/// "in multiple lanes" and "rear axle in an intersection" are only needed at collisions: [`multiple_lanes`],
/// [`exposed`].
#[derive(Debug, Clone, Copy, Default)]
struct EgoArea {
    non_drivable: Tri,
    oncoming: Tri,
    centre_in_intersection: Tri,
}

/// The ego footprint (rear-axle state → rectangle) at one state.
fn ego_rect(state: &[f64], shape: &EgoShape) -> Rect {
    safety::footprint(&[state[X], state[Y], state[HEADING]], shape)
}

fn in_layer(layer: Option<&Layer<'_>>, near: &[usize], p: Point2<f64>) -> Tri {
    layer.map(|l| l.contains(near, p.x, p.y))
}

fn ego_area(inp: &Inputs<'_>, near: &Near, f: usize, rect: &Rect, hints: &mut Hints) -> EgoArea {
    let non_drivable = inp.drivable.map(|a| {
        rect.corners()
            .iter()
            .any(|c| !a.contains_from(&near.drivable, c.x, c.y, &mut hints.drivable))
    });
    // oncoming: the centre in no on-route lane
    let oncoming = inp.lanes.map(|l| {
        !(l.offsets[f]..l.offsets[f + 1]).any(|k| {
            l.on_route[k] != 0 && l.polygons[l.ids[k]].contains(rect.centre.x, rect.centre.y)
        })
    });
    EgoArea {
        non_drivable,
        oncoming,
        centre_in_intersection: inp.intersections.map(|l| {
            l.contains_from(
                &near.intersections,
                rect.centre.x,
                rect.centre.y,
                &mut hints.intersection,
            )
        }),
    }
}

/// NAVSIM's "in multiple lanes": corners in more than one of the frame's lanes and no lane holding all four.
fn multiple_lanes(inp: &Inputs<'_>, f: usize, rect: &Rect) -> Tri {
    let l = inp.lanes?;
    let corners = rect.corners();
    let (mut touched, mut some_has_all) = (0usize, false);
    for k in l.offsets[f]..l.offsets[f + 1] {
        let poly = &l.polygons[l.ids[k]];
        let inside = corners.iter().filter(|c| poly.contains(c.x, c.y)).count();
        touched += (inside > 0) as usize;
        some_has_all |= inside == 4;
    }
    Some(touched > 1 && !some_has_all)
}

/// NAVSIM's `ego_in_multiple_lanes_or_nondrivable_area` at one step (three-valued).
fn exposed(inp: &Inputs<'_>, f: usize, rect: &Rect, area: &EgoArea) -> Tri {
    if area.non_drivable == Some(true) {
        return Some(true);
    }
    tri_or(area.non_drivable, multiple_lanes(inp, f, rect))
}

/// nuPlan's relative angle of the agent's position seen from the ego pose, radians in [0, π]; NaN when the
/// two points coincide (nuPlan divides by a zero norm: neither ahead nor behind).
pub fn relative_angle(ego: &[f64; 3], agent: Point2<f64>) -> f64 {
    let v = Vector2::new(agent.x - ego[0], agent.y - ego[1]);
    let norm = v.norm();
    if norm == 0.0 {
        return f64::NAN;
    }
    let dot = (ego[2].cos() * v.x + ego[2].sin() * v.y) / norm;
    dot.clamp(-1.0, 1.0).acos()
}

/// Whether the segment a → b intersects the rectangle (touching counts, as shapely's `intersects`):
/// separating axes on the rectangle's two axes and the segment's normal.
pub fn segment_hits_rect(a: Point2<f64>, b: Point2<f64>, r: &Rect) -> bool {
    let n = Vector2::new(-r.axis.y, r.axis.x);
    let d = b - a;
    let mut axes = vec![r.axis, n];
    if d.norm() > 0.0 {
        axes.push(Vector2::new(-d.y, d.x) / d.norm());
    }
    for u in axes {
        let (pa, pb) = ((a - r.centre).dot(&u), (b - r.centre).dot(&u));
        let radius = r.half_length * r.axis.dot(&u).abs() + r.half_width * n.dot(&u).abs();
        if pa.min(pb) > radius || pa.max(pb) < -radius {
            return false;
        }
    }
    true
}

/// Collision classes of nuPlan's `CollisionType`, as `get_collision_type` decides them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CollisionType {
    StoppedEgo,
    StoppedTrack,
    ActiveRear,
    ActiveFront,
    ActiveLateral,
}

/// `get_collision_type` for an ego state, its footprint and an overlapping agent box (8 values).
pub fn collision_type(state: &[f64], ego: &Rect, b: &[f64], cfg: &Config) -> CollisionType {
    let ego_speed = state[VX].hypot(state[VY]);
    if ego_speed <= cfg.collision_stopped_speed {
        return CollisionType::StoppedEgo;
    }
    if b[7] != KIND_AGENT || b[5].hypot(b[6]) <= cfg.collision_stopped_speed {
        return CollisionType::StoppedTrack;
    }
    let axle = [state[X], state[Y], state[HEADING]];
    if relative_angle(&axle, Point2::new(b[0], b[1])) > cfg.behind {
        return CollisionType::ActiveRear;
    }
    let c = ego.corners(); // front-left, front-right, …: the front bumper is c[0] → c[1]
    if segment_hits_rect(c[0], c[1], &Rect::new(b[0], b[1], b[2], b[3], b[4])) {
        return CollisionType::ActiveFront;
    }
    CollisionType::ActiveLateral
}

fn box_ok(b: &[f64]) -> bool {
    b.iter().all(|v| v.is_finite())
        && b[3] > 0.0
        && b[4] > 0.0
        && (b[7] == KIND_AGENT || b[7] == KIND_OBJECT)
}

/// The leading finite rows of a polyline (R·2) when the rest is NaN padding and at least two remain.
fn polyline(line: &[f64]) -> Option<&[f64]> {
    let m = line
        .chunks_exact(2)
        .take_while(|p| p[0].is_finite() && p[1].is_finite())
        .count();
    let rest_is_padding = line[2 * m..].chunks_exact(2).all(|p| p[0].is_nan());
    (m >= 2 && rest_is_padding).then(|| &line[..2 * m])
}

/// Distance of `p` to the polyline and the arc length of its nearest point (shapely's `distance` and
/// `project`; ties go to the first segment).
pub fn project(line: &[f64], p: Point2<f64>) -> (f64, f64) {
    let (mut best, mut along, mut walked) = (f64::INFINITY, 0.0, 0.0);
    for i in 0..line.len() / 2 - 1 {
        let a = Point2::new(line[2 * i], line[2 * i + 1]);
        let d = Point2::new(line[2 * i + 2], line[2 * i + 3]) - a;
        let len2 = d.norm_squared();
        let t = if len2 > 0.0 {
            ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let dist = (a + d * t - p).norm();
        if dist < best {
            best = dist;
            along = walked + t * len2.sqrt();
        }
        walked += len2.sqrt();
    }
    (best, along)
}

/// A frame's agents at every step: boxes (S·A·8) and their rectangles (S·A; a NaN centre is an absent slot).
struct FrameAgents<'a> {
    boxes: &'a [f64],
    rects: Vec<Rect>,
    /// Bounding-circle radius of each rectangle, m.
    radius: Vec<f64>,
    /// Per slot over its present steps: smallest centre x, y, largest centre x, y, largest radius (an absent
    /// slot: +inf, +inf, -inf, -inf, -inf).
    slot_bounds: Vec<[f64; 5]>,
    slots: usize,
}

impl FrameAgents<'_> {
    #[inline]
    fn at(&self, s: usize, a: usize) -> (&[f64], &Rect) {
        let i = s * self.slots + a;
        (
            &self.boxes[i * AGENT_VALUES..(i + 1) * AGENT_VALUES],
            &self.rects[i],
        )
    }

    /// Whether the ego rectangle (bounding radius `ego_radius`) overlaps slot `a` at step `s`: the bounding
    /// circles first (no square root), then the exact test. An absent slot (NaN centre) never does.
    #[inline]
    fn hits(&self, ego: &Rect, ego_radius: f64, s: usize, a: usize) -> bool {
        let i = s * self.slots + a;
        let r = &self.rects[i];
        let reach = ego_radius + self.radius[i];
        let d2 = (r.centre - ego.centre).norm_squared();
        d2 < reach * reach && ego.overlaps(r)
    }
}

/// One plan's sub-scores and reason codes.
#[allow(clippy::too_many_arguments)]
fn score_plan(
    inp: &Inputs<'_>,
    near: &Near,
    n: usize,
    agents: Result<&FrameAgents<'_>, u8>,
    future: &[usize],
    out: &mut [f64],
    codes: &mut [u8],
) {
    let s_n = inp.steps;
    let states = &inp.states[n * s_n * STATE_SIZE..(n + 1) * s_n * STATE_SIZE];
    if !states.iter().all(|v| v.is_finite()) {
        out.fill(f64::NAN);
        codes.fill(BAD_STATES);
        return;
    }
    let f = inp.frame[n];
    let cfg = &inp.config;
    let st = |s: usize| &states[s * STATE_SIZE..(s + 1) * STATE_SIZE];
    let rects: Vec<Rect> = (0..s_n).map(|s| ego_rect(st(s), &inp.shape)).collect();
    let mut hints = Hints {
        drivable: usize::MAX,
        intersection: usize::MAX,
    };
    let areas: Vec<EgoArea> = (0..s_n)
        .map(|s| ego_area(inp, near, f, &rects[s], &mut hints))
        .collect();
    let mut put = |col: usize, v: Result<f64, u8>| match v {
        Ok(x) => {
            out[col] = x;
            codes[col] = OK;
        }
        Err(c) => {
            out[col] = f64::NAN;
            codes[col] = c;
        }
    };

    // dac: any corner off the drivable area at any step (NAVSIM's NON_DRIVABLE_AREA over all states)
    put(
        DAC,
        match areas
            .iter()
            .map(|a| a.non_drivable)
            .collect::<Option<Vec<bool>>>()
        {
            None => Err(NO_DRIVABLE),
            Some(v) => Ok(if v.iter().any(|&b| b) { 0.0 } else { 1.0 }),
        },
    );

    // nc and ttc need the agents
    match agents {
        Err(code) => {
            put(NC, Err(code));
            put(TTC, Err(code));
        }
        Ok(fa) => {
            let candidates = near_tracks(states, s_n, fa, &inp.shape, cfg);
            put(
                NC,
                no_collision(inp, f, states, &rects, &areas, &candidates, fa),
            );
            put(
                TTC,
                time_to_collision(
                    inp,
                    near,
                    f,
                    states,
                    &rects,
                    &areas,
                    &candidates,
                    fa,
                    future,
                ),
            );
        }
    }

    // ddc: oncoming progress of the centre over a window, intersections excluded
    put(DDC, driving_direction(inp, f, &rects, &areas));

    // ep (raw): progress of the centre along the route
    put(
        EP,
        match &near.route {
            None => Err(NO_ROUTE),
            Some(line) => {
                let (_, a) = line.project(rects[0].centre);
                let (_, b) = line.project(rects[s_n - 1].centre);
                Ok((b - a).max(0.0))
            }
        },
    );

    // lk: deviation from the centreline beyond the limit for a continuous window outside intersections
    put(
        LK,
        match &near.centreline {
            None => Err(NO_CENTRELINE),
            Some(line) => lane_keeping(cfg, line, &rects, &areas),
        },
    );
}

/// Track slots that come near the ego at any step (a bounding-box prefilter; exact tests follow).
fn near_tracks(
    states: &[f64],
    s_n: usize,
    fa: &FrameAgents<'_>,
    shape: &EgoShape,
    cfg: &Config,
) -> Vec<usize> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let mut vmax = 0.0_f64;
    for s in 0..s_n {
        let v = &states[s * STATE_SIZE..(s + 1) * STATE_SIZE];
        lo = [lo[0].min(v[X]), lo[1].min(v[Y])];
        hi = [hi[0].max(v[X]), hi[1].max(v[Y])];
        vmax = vmax.max(v[VX].hypot(v[VY]));
    }
    let reach =
        (shape.offset.abs() + shape.length * 0.5).hypot(shape.width * 0.5) + vmax * cfg.ttc_horizon;
    // a slot whose box of centres over all steps, widened by the reach and its largest radius, misses the
    // plan's box misses it at every step; the others are tested step by step
    (0..fa.slots)
        .filter(|&a| {
            let b = fa.slot_bounds[a];
            let m = reach + b[4];
            b[0] <= hi[0] + m && b[2] >= lo[0] - m && b[1] <= hi[1] + m && b[3] >= lo[1] - m
        })
        .filter(|&a| {
            (0..s_n).any(|s| {
                let i = s * fa.slots + a;
                let m = reach + fa.radius[i];
                let c = fa.rects[i].centre;
                c.x >= lo[0] - m && c.x <= hi[0] + m && c.y >= lo[1] - m && c.y <= hi[1] + m
            })
        })
        .collect()
}

/// NAVSIM's `_calculate_no_at_fault_collision` for one plan.
fn no_collision(
    inp: &Inputs<'_>,
    f: usize,
    states: &[f64],
    rects: &[Rect],
    areas: &[EgoArea],
    candidates: &[usize],
    fa: &FrameAgents<'_>,
) -> Result<f64, u8> {
    let cfg = &inp.config;
    let mut score = 1.0_f64;
    let mut ignored = vec![false; candidates.len()];
    let mut undetermined = false;
    let ego_radius = (0.5 * inp.shape.length).hypot(0.5 * inp.shape.width);
    for (s, ego) in rects.iter().enumerate() {
        let state = &states[s * STATE_SIZE..(s + 1) * STATE_SIZE];
        for (j, &a) in candidates.iter().enumerate() {
            if ignored[j] || !fa.hits(ego, ego_radius, s, a) {
                continue;
            }
            let (b, _) = fa.at(s, a);
            let at_fault = match collision_type(state, ego, b, cfg) {
                CollisionType::StoppedTrack | CollisionType::ActiveFront => Some(true),
                CollisionType::ActiveLateral => exposed(inp, f, ego, &areas[s]),
                CollisionType::StoppedEgo | CollisionType::ActiveRear => Some(false),
            };
            match at_fault {
                Some(true) if b[7] == KIND_AGENT => return Ok(0.0), // nothing can change a 0
                Some(true) => score = score.min(0.5),
                Some(false) => ignored[j] = true,
                None => {
                    undetermined = true;
                    ignored[j] = true;
                }
            }
        }
    }
    if score == 0.0 || !undetermined {
        Ok(score)
    } else {
        Err(UNDETERMINED)
    }
}

/// NAVSIM's `_calculate_ttc` for one plan: the footprint projected 0, 0.3, 0.6, 0.9 s ahead at constant
/// speed along the heading against the agents' boxes at those future steps.
#[allow(clippy::too_many_arguments)]
fn time_to_collision(
    inp: &Inputs<'_>,
    near: &Near,
    f: usize,
    states: &[f64],
    rects: &[Rect],
    areas: &[EgoArea],
    candidates: &[usize],
    fa: &FrameAgents<'_>,
    future: &[usize],
) -> Result<f64, u8> {
    let cfg = &inp.config;
    let last = *future.iter().max().unwrap_or(&0);
    let s_n = inp.steps;
    if s_n <= last {
        return Ok(1.0);
    }
    let mut ignored = vec![false; candidates.len()];
    let mut undetermined = false;
    let ego_radius = (0.5 * inp.shape.length).hypot(0.5 * inp.shape.width);
    for s in 0..s_n - last {
        let state = &states[s * STATE_SIZE..(s + 1) * STATE_SIZE];
        let speed = state[VX].hypot(state[VY]);
        if speed < cfg.ttc_stopped_speed {
            continue;
        }
        let axle = [state[X], state[Y], state[HEADING]];
        let dir = Vector2::new(state[HEADING].cos(), state[HEADING].sin()) * speed;
        for &k in future {
            let mut ego = rects[s];
            ego.centre += dir * (k as f64 * cfg.dt);
            for (j, &a) in candidates.iter().enumerate() {
                if ignored[j] || !fa.hits(&ego, ego_radius, s + k, a) {
                    continue;
                }
                let (b, _) = fa.at(s + k, a);
                let centre = Point2::new(b[0], b[1]);
                let angle = relative_angle(&axle, centre);
                let ahead = angle < cfg.ahead;
                let behind = angle > cfg.behind;
                let infraction = if ahead {
                    Some(true)
                } else if behind {
                    Some(false)
                } else {
                    let axle = in_layer(
                        inp.intersections,
                        &near.intersections,
                        Point2::new(state[X], state[Y]),
                    );
                    tri_or(exposed(inp, f, &rects[s], &areas[s]), axle)
                };
                match infraction {
                    Some(true) => return Ok(0.0),
                    Some(false) => ignored[j] = true,
                    None => {
                        undetermined = true;
                        ignored[j] = true;
                    }
                }
            }
        }
    }
    if undetermined {
        Err(UNDETERMINED)
    } else {
        Ok(1.0)
    }
}

/// NAVSIM's `_calculate_driving_direction_compliance` for one plan.
fn driving_direction(
    inp: &Inputs<'_>,
    f: usize,
    rects: &[Rect],
    areas: &[EgoArea],
) -> Result<f64, u8> {
    let cfg = &inp.config;
    let Some(lanes) = inp.lanes else {
        return Err(NO_LANES);
    };
    if !(lanes.offsets[f]..lanes.offsets[f + 1]).any(|k| lanes.on_route[k] != 0) {
        return Err(NO_ROUTE_LANES);
    }
    if inp.intersections.is_none() {
        return Err(NO_INTERSECTIONS);
    }
    let mut progress = vec![0.0; rects.len()];
    for s in 1..rects.len() {
        let oncoming = areas[s].oncoming == Some(true);
        let crossing = areas[s].centre_in_intersection == Some(true);
        if oncoming && !crossing {
            progress[s] = (rects[s].centre - rects[s - 1].centre).norm();
        }
    }
    let h = cfg.ddc_steps();
    let worst = (0..rects.len())
        .map(|t| progress[t.saturating_sub(h)..=t].iter().sum::<f64>())
        .fold(0.0_f64, f64::max);
    Ok(if worst < cfg.ddc_compliance {
        1.0
    } else if worst < cfg.ddc_violation {
        0.5
    } else {
        0.0
    })
}

/// NAVSIM's `_calculate_lane_keeping` for one plan (steps in an intersection neither count nor reset).
fn lane_keeping(
    cfg: &Config,
    line: &Line<'_>,
    rects: &[Rect],
    areas: &[EgoArea],
) -> Result<f64, u8> {
    let need = cfg.lk_steps();
    let mut run = 0usize;
    for (s, r) in rects.iter().enumerate() {
        match areas[s].centre_in_intersection {
            None => return Err(NO_INTERSECTIONS),
            Some(true) => continue,
            Some(false) => {}
        }
        let (dev, _) = line.project(r.centre);
        run = if dev > cfg.lk_limit { run + 1 } else { 0 };
        if run >= need {
            return Ok(0.0);
        }
    }
    Ok(1.0)
}

/// Per-frame validity of the agents' boxes (F): false when any present slot is degenerate.
fn boxes_valid(agents: Option<(&[f64], usize)>, frames: usize, steps: usize) -> Vec<bool> {
    match agents {
        None => vec![true; frames],
        Some((a, slots)) => a
            .par_chunks(steps * slots * AGENT_VALUES)
            .map(|fr| {
                fr.chunks_exact(AGENT_VALUES)
                    .all(|b| b[0].is_nan() || box_ok(b))
            })
            .collect::<Vec<bool>>(),
    }
}

/// The first degenerate box of frame `f`: (step, slot), for error messages.
pub fn first_bad_box(
    agents: &[f64],
    slots: usize,
    steps: usize,
    f: usize,
) -> Option<(usize, usize)> {
    let fr = &agents[f * steps * slots * AGENT_VALUES..(f + 1) * steps * slots * AGENT_VALUES];
    fr.chunks_exact(AGENT_VALUES)
        .position(|b| !(b[0].is_nan() || box_ok(b)))
        .map(|i| (i / slots, i % slots))
}

/// Sub-scores of every plan: values (N·6) with NaN where n/a, and reason codes (N·6); columns
/// [`NC`], [`DAC`], [`DDC`], [`EP`] (raw metres), [`TTC`], [`LK`].
///
/// Errors (a `CoreError`, for the whole batch): array lengths that disagree, a frame index ≥ F, S < 2,
/// lane lists that do not fit, a bad ego shape or config. Bad values inside a frame are reason codes.
pub fn subscores<'a>(inp: &Inputs<'a>) -> CoreResult<(Vec<f64>, Vec<u8>)> {
    inp.shape.check()?;
    inp.config.check()?;
    let s_n = inp.steps;
    if s_n < 2 {
        return Err(CoreError::Shape(format!(
            "states need at least 2 steps (the initial state and one more), got {s_n}"
        )));
    }
    if !inp.states.len().is_multiple_of(s_n * STATE_SIZE) {
        return Err(CoreError::Shape(format!(
            "states have {} values, not a multiple of S·11 = {}",
            inp.states.len(),
            s_n * STATE_SIZE
        )));
    }
    let n = inp.states.len() / (s_n * STATE_SIZE);
    if inp.frame.len() != n {
        return Err(CoreError::Shape(format!(
            "frame has {} entries but states hold {n} plans",
            inp.frame.len()
        )));
    }
    if let Some(&f) = inp.frame.iter().find(|&&f| f >= inp.frames) {
        return Err(CoreError::Argument(format!(
            "frame index {f} is out of range for {} frames",
            inp.frames
        )));
    }
    let fr = inp.frames;
    if let Some((a, slots)) = inp.agents {
        let want = fr * s_n * slots * AGENT_VALUES;
        if a.len() != want {
            return Err(CoreError::Shape(format!(
                "agents have {} values; expected {want} for shape ({fr}, {s_n}, {slots}, {AGENT_VALUES})",
                a.len()
            )));
        }
    }
    for (name, line) in [("route", inp.route), ("centreline", inp.centreline)] {
        if let Some((l, len)) = line {
            if l.len() != fr * len * 2 {
                return Err(CoreError::Shape(format!(
                    "{name} has {} values; expected {} for shape ({fr}, {len}, 2)",
                    l.len(),
                    fr * len * 2
                )));
            }
        }
    }
    if let Some(l) = inp.lanes {
        if l.offsets.len() != fr + 1
            || l.offsets.windows(2).any(|w| w[0] > w[1])
            || l.offsets.last().copied().unwrap_or(0) > l.ids.len()
            || l.ids.len() != l.on_route.len()
        {
            return Err(CoreError::Shape(format!(
                "lane lists need offsets (F + 1 = {}, non-decreasing, ending ≤ {} ids) and one on-route flag per id",
                fr + 1,
                l.ids.len()
            )));
        }
        if let Some(&id) = l.ids.iter().find(|&&id| id >= l.polygons.len()) {
            return Err(CoreError::Argument(format!(
                "lane id {id} is out of range for {} lane polygons",
                l.polygons.len()
            )));
        }
    }
    if let Some(Layer::Mask(m)) = inp.drivable {
        m.check()?;
    }
    let boxes_ok = boxes_valid(inp.agents, fr, s_n);
    let future = inp.config.ttc_steps();
    // plans grouped by frame: a frame's agents' rectangles are built once for all its plans
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| inp.frame[i]);
    let groups: Vec<&[usize]> = order
        .chunk_by(|a, b| inp.frame[*a] == inp.frame[*b])
        .collect();
    type Scored = (usize, [f64; SCORES], [u8; SCORES]);
    let scored: Vec<Vec<Scored>> = groups
        .par_iter()
        .map(|g| {
            let f = inp.frame[g[0]];
            let fa = match inp.agents {
                None => Err(NO_AGENTS),
                Some(_) if !boxes_ok[f] => Err(BAD_BOX),
                Some((a, slots)) => {
                    let boxes =
                        &a[f * s_n * slots * AGENT_VALUES..(f + 1) * s_n * slots * AGENT_VALUES];
                    let rects: Vec<Rect> = boxes
                        .chunks_exact(AGENT_VALUES)
                        .map(|b| Rect::new(b[0], b[1], b[2], b[3], b[4]))
                        .collect();
                    let radius: Vec<f64> = rects
                        .iter()
                        .map(|r| r.half_length.hypot(r.half_width))
                        .collect();
                    let mut slot_bounds = vec![
                        [
                            f64::INFINITY,
                            f64::INFINITY,
                            f64::NEG_INFINITY,
                            f64::NEG_INFINITY,
                            f64::NEG_INFINITY
                        ];
                        slots
                    ];
                    for (i, r) in rects.iter().enumerate() {
                        let c = r.centre;
                        if c.x.is_nan() || c.y.is_nan() || radius[i].is_nan() {
                            continue; // an absent slot at this step
                        }
                        let b = &mut slot_bounds[i % slots];
                        *b = [
                            b[0].min(c.x),
                            b[1].min(c.y),
                            b[2].max(c.x),
                            b[3].max(c.y),
                            b[4].max(radius[i]),
                        ];
                    }
                    Ok(FrameAgents {
                        boxes,
                        rects,
                        radius,
                        slot_bounds,
                        slots,
                    })
                }
            };
            // the region of the frame's plans (finite states only), widened by the ego's reach
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for &i in g.iter() {
                for st in inp.states[i * s_n * STATE_SIZE..(i + 1) * s_n * STATE_SIZE]
                    .chunks_exact(STATE_SIZE)
                {
                    if st[X].is_finite() && st[Y].is_finite() {
                        lo = [lo[0].min(st[X]), lo[1].min(st[Y])];
                        hi = [hi[0].max(st[X]), hi[1].max(st[Y])];
                    }
                }
            }
            let reach = inp.shape.offset.abs()
                + (0.5 * inp.shape.length).hypot(0.5 * inp.shape.width)
                + 1.0;
            let (lo, hi) = (
                [lo[0] - reach, lo[1] - reach],
                [hi[0] + reach, hi[1] + reach],
            );
            let line = |l: Option<(&'a [f64], usize)>| {
                l.and_then(|(r, len)| polyline(&r[f * len * 2..(f + 1) * len * 2]))
                    .map(Line::new)
            };
            let near = Near {
                drivable: inp.drivable.map_or_else(Vec::new, |l| l.near(lo, hi)),
                intersections: inp.intersections.map_or_else(Vec::new, |l| l.near(lo, hi)),
                route: line(inp.route),
                centreline: line(inp.centreline),
            };
            g.iter()
                .map(|&i| {
                    let (mut v, mut c) = ([0.0; SCORES], [0u8; SCORES]);
                    score_plan(
                        inp,
                        &near,
                        i,
                        fa.as_ref().map_err(|e| *e),
                        &future,
                        &mut v,
                        &mut c,
                    );
                    (i, v, c)
                })
                .collect()
        })
        .collect();
    let mut values = vec![0.0; n * SCORES];
    let mut codes = vec![0u8; n * SCORES];
    for (i, v, c) in scored.into_iter().flatten() {
        values[i * SCORES..(i + 1) * SCORES].copy_from_slice(&v);
        codes[i * SCORES..(i + 1) * SCORES].copy_from_slice(&c);
    }
    Ok((values, codes))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHAPE: EgoShape = EgoShape {
        length: 4.0,
        width: 2.0,
        offset: 1.0,
        min_step: 0.0,
    };

    /// A straight run along +x at `speed` m/s, S states 0.1 s apart, starting at x0.
    fn straight(x0: f64, y: f64, speed: f64, steps: usize) -> Vec<f64> {
        let mut v = Vec::new();
        for s in 0..steps {
            let mut st = [0.0; STATE_SIZE];
            st[X] = x0 + speed * 0.1 * s as f64;
            st[Y] = y;
            st[VX] = speed;
            v.extend(st);
        }
        v
    }

    fn agent_at(steps: usize, x: f64, y: f64, vx: f64, kind: f64) -> Vec<f64> {
        (0..steps)
            .flat_map(|s| [x + vx * 0.1 * s as f64, y, 0.0, 4.0, 2.0, vx, 0.0, kind])
            .collect()
    }

    fn inputs<'a>(
        states: &'a [f64],
        frame: &'a [usize],
        agents: Option<(&'a [f64], usize)>,
    ) -> Inputs<'a> {
        Inputs {
            states,
            steps: 31,
            frame,
            frames: 1,
            agents,
            drivable: None,
            lanes: None,
            intersections: None,
            route: None,
            centreline: None,
            shape: SHAPE,
            config: Config::default(),
        }
    }

    #[test]
    fn hitting_a_stopped_car_is_at_fault_and_an_object_half() {
        let states = straight(0.0, 0.0, 10.0, 31);
        let car = agent_at(31, 20.0, 0.0, 0.0, KIND_AGENT);
        let (v, c) = subscores(&inputs(&states, &[0], Some((&car, 1)))).unwrap();
        assert_eq!((v[NC], c[NC]), (0.0, OK));
        assert_eq!(v[TTC], 0.0);
        let cone = agent_at(31, 20.0, 0.0, 0.0, KIND_OBJECT);
        let (v, _) = subscores(&inputs(&states, &[0], Some((&cone, 1)))).unwrap();
        assert_eq!(v[NC], 0.5);
        // no map: dac, ddc n/a with their reasons; no route: ep n/a
        let (v, c) = subscores(&inputs(&states, &[0], Some((&cone, 1)))).unwrap();
        assert!(v[DAC].is_nan() && c[DAC] == NO_DRIVABLE);
        assert!(v[DDC].is_nan() && c[DDC] == NO_LANES);
        assert!(v[EP].is_nan() && c[EP] == NO_ROUTE);
    }

    #[test]
    fn a_rear_end_by_a_follower_is_not_at_fault() {
        // ego at 5 m/s, a car behind at 15 m/s that runs into it
        let states = straight(0.0, 0.0, 5.0, 31);
        let car = agent_at(31, -12.0, 0.0, 15.0, KIND_AGENT);
        let (v, c) = subscores(&inputs(&states, &[0], Some((&car, 1)))).unwrap();
        assert_eq!((v[NC], c[NC]), (1.0, OK));
        // NAVSIM's TTC sees the follower 0.9 s later *ahead* of the ego's rear axle of now (the axle is not
        // projected, the footprint is): an infraction, as in NAVSIM
        assert_eq!((v[TTC], c[TTC]), (0.0, OK));
        // a slower follower that never reaches the ego: no event
        let car = agent_at(31, -12.0, 0.0, 5.0, KIND_AGENT);
        let (v, _) = subscores(&inputs(&states, &[0], Some((&car, 1)))).unwrap();
        assert_eq!((v[NC], v[TTC]), (1.0, 1.0));
    }

    #[test]
    fn a_lateral_collision_needs_the_map() {
        // a car alongside that drifts into the ego: its centre is beside the ego (not ahead, not behind)
        let states = straight(0.0, 0.0, 5.0, 31);
        let car: Vec<f64> = (0..31)
            .flat_map(|s| {
                let x = 0.5 + 0.5 * s as f64;
                [
                    x,
                    3.5 - 0.1 * s as f64,
                    0.0,
                    4.0,
                    2.0,
                    5.0,
                    -1.0,
                    KIND_AGENT,
                ]
            })
            .collect();
        let (v, c) = subscores(&inputs(&states, &[0], Some((&car, 1)))).unwrap();
        assert!(v[NC].is_nan() && c[NC] == UNDETERMINED, "{v:?} {c:?}");
        // a road everywhere and one lane holding the ego: not at fault
        let xy = [-1e3, -1e3, 1e3, -1e3, 1e3, 1e3, -1e3, 1e3];
        let parts = polygon_parts(&[0, 4], &[0, 1]).unwrap();
        let road = Layer::polygons(&xy, &parts).unwrap();
        let lanes = Lanes {
            polygons: single_polygons(&xy, &parts).unwrap(),
            offsets: &[0, 1],
            ids: &[0],
            on_route: &[1],
        };
        let mut inp = inputs(&states, &[0], Some((&car, 1)));
        inp.drivable = Some(&road);
        inp.lanes = Some(&lanes);
        let (v, _) = subscores(&inp).unwrap();
        assert_eq!(v[NC], 1.0);
        assert_eq!(v[DAC], 1.0);
    }

    #[test]
    fn segment_rectangle_intersection() {
        let r = Rect::new(0.0, 0.0, 0.0, 2.0, 2.0);
        assert!(segment_hits_rect(
            Point2::new(-3.0, 0.0),
            Point2::new(3.0, 0.0),
            &r
        ));
        assert!(segment_hits_rect(
            Point2::new(0.5, 0.5),
            Point2::new(0.6, 0.6),
            &r
        ));
        assert!(!segment_hits_rect(
            Point2::new(-3.0, 1.5),
            Point2::new(3.0, 1.5),
            &r
        ));
        // diagonal passing the corner outside: AABB projections overlap but the segment normal separates
        assert!(!segment_hits_rect(
            Point2::new(0.0, 2.5),
            Point2::new(2.5, 0.0),
            &r
        ));
        assert!(segment_hits_rect(
            Point2::new(0.0, 1.9),
            Point2::new(1.9, 0.0),
            &r
        ));
    }

    #[test]
    fn projection_is_shapely_project() {
        let line = [0.0, 0.0, 10.0, 0.0, 10.0, 10.0];
        let (d, a) = project(&line, Point2::new(5.0, 2.0));
        assert!((d - 2.0).abs() < 1e-12 && (a - 5.0).abs() < 1e-12);
        let (d, a) = project(&line, Point2::new(12.0, 4.0));
        assert!((d - 2.0).abs() < 1e-12 && (a - 14.0).abs() < 1e-12);
        assert!(polyline(&[0.0, 0.0, 1.0, 0.0, f64::NAN, f64::NAN]).is_some());
        assert!(polyline(&[0.0, 0.0, f64::NAN, f64::NAN, 1.0, 0.0]).is_none());
        assert!(polyline(&[0.0, 0.0, f64::NAN, f64::NAN]).is_none());
    }

    #[test]
    fn line_projection_is_project_value_for_value() {
        // a zigzag with a repeated point (a zero-length segment) and points on, between and beyond it
        let xy = [
            0.0, 0.0, 3.0, 1.0, 3.0, 1.0, 5.0, -2.0, 9.5, -2.0, 12.0, 4.0,
        ];
        let line = Line::new(&xy);
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut points: Vec<Point2<f64>> = (0..2000)
            .map(|_| Point2::new(-5.0 + 22.0 * next(), -8.0 + 16.0 * next()))
            .collect();
        points.extend(xy.chunks_exact(2).map(|p| Point2::new(p[0], p[1])));
        points.push(Point2::new(4.0, -0.5)); // equidistant from two segments: the first wins in both
        for p in points {
            let (a, b) = (project(&xy, p), line.project(p));
            assert_eq!(a.0.to_bits(), b.0.to_bits(), "{p:?}");
            assert_eq!(a.1.to_bits(), b.1.to_bits(), "{p:?}");
        }
    }

    #[test]
    fn bad_input_is_a_reason_or_an_error() {
        let mut states = straight(0.0, 0.0, 5.0, 31);
        states[40] = f64::NAN;
        let (v, c) = subscores(&inputs(&states, &[0], None)).unwrap();
        assert!(v.iter().all(|x| x.is_nan()) && c.iter().all(|&x| x == BAD_STATES));
        let states = straight(0.0, 0.0, 5.0, 31);
        let mut car = agent_at(31, 20.0, 0.0, 0.0, KIND_AGENT);
        car[3 * AGENT_VALUES + 3] = 0.0;
        let (v, c) = subscores(&inputs(&states, &[0], Some((&car, 1)))).unwrap();
        assert!(v[NC].is_nan() && c[NC] == BAD_BOX && c[TTC] == BAD_BOX);
        assert_eq!(first_bad_box(&car, 1, 31, 0), Some((3, 0)));
        assert!(subscores(&inputs(&states, &[1], None)).is_err());
        assert!(subscores(&inputs(&states[..30], &[0], None)).is_err());
    }
}
