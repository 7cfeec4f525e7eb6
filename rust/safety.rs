//! Safety geometry (docs/definitions.md#safety): the ego footprint along a trajectory,
//! exact rotated-rectangle overlap with agents' boxes, and drivable-area tests against a
//! raster mask or polygons.
//!
//! Frames: a trajectory is in the **ego frame** of its keyframe (x forward, y left, metres,
//! origin at the nuScenes `ego_pose`, i.e. the rear-axle centre); `pose` = (x, y, yaw) of
//! that keyframe in the global (map) frame. SE(2) transforms are nalgebra `Isometry2`s.
//!
//! The footprint at step k is a `length` × `width` rectangle whose centre lies `offset`
//! metres ahead of the reference point p_k along the heading θ_k; θ_k is the direction of the
//! segment p_{k−1} → p_k (p_0 = the origin, θ_0 = 0, the ego's own heading), kept from the step
//! before when that segment is shorter than `min_step` metres (BEV-Planner's rule).
//!
//! Everything here is plain Rust, tested without Python; `python/safety.rs` binds it.

use nalgebra::{Isometry2, Point2, Vector2};
use rayon::prelude::*;

use crate::definitions;
use crate::error::{CoreError, CoreResult};

/// Frames per parallel task.
const FRAMES_PER_TASK: usize = 256;

/// Values per agent box: centre x, centre y, yaw, length, width (global frame, metres, radians).
pub const BOX_VALUES: usize = 5;

/// Values per footprint test: the four corners (front-left, front-right, rear-right, rear-left)
/// then the reference point itself.
pub const TEST_POINTS: usize = 5;

/// Mask lookup outcomes.
pub const OFF: u8 = 0;
pub const ON: u8 = 1;
/// The point falls outside the mask image (counted as off the drivable area, and reported).
pub const OUTSIDE: u8 = 2;

/// The ego rectangle and the heading rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EgoShape {
    /// Along the heading, metres.
    pub length: f64,
    /// Across the heading, metres.
    pub width: f64,
    /// How far the rectangle's centre lies ahead of the reference point (the rear axle), metres.
    pub offset: f64,
    /// A step shorter than this keeps the previous heading, metres.
    pub min_step: f64,
}

impl Default for EgoShape {
    /// lightemma's ego box and heading rule ([`crate::definitions`]).
    fn default() -> Self {
        EgoShape {
            length: definitions::EGO_LENGTH,
            width: definitions::EGO_WIDTH,
            offset: definitions::EGO_OFFSET,
            min_step: definitions::MIN_STEP,
        }
    }
}

impl EgoShape {
    pub fn check(&self) -> CoreResult<()> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !ok(self.length) || !ok(self.width) {
            return Err(CoreError::Argument(format!(
                "the ego box must have a positive finite size, got length {} × width {}",
                self.length, self.width
            )));
        }
        if !self.offset.is_finite() || !self.min_step.is_finite() || self.min_step < 0.0 {
            return Err(CoreError::Argument(format!(
                "ego offset must be finite and min_step finite and ≥ 0, got offset {} and min_step {}",
                self.offset, self.min_step
            )));
        }
        Ok(())
    }
}

/// A rectangle: centre, unit heading (cos, sin), half length, half width.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub centre: Point2<f64>,
    pub axis: Vector2<f64>,
    pub half_length: f64,
    pub half_width: f64,
}

impl Rect {
    pub fn new(cx: f64, cy: f64, yaw: f64, length: f64, width: f64) -> Self {
        Rect {
            centre: Point2::new(cx, cy),
            axis: Vector2::new(yaw.cos(), yaw.sin()),
            half_length: 0.5 * length,
            half_width: 0.5 * width,
        }
    }

    fn normal(&self) -> Vector2<f64> {
        Vector2::new(-self.axis.y, self.axis.x)
    }

    /// Corners: front-left, front-right, rear-right, rear-left.
    pub fn corners(&self) -> [Point2<f64>; 4] {
        let a = self.axis * self.half_length;
        let b = self.normal() * self.half_width;
        [
            self.centre + a + b,
            self.centre + a - b,
            self.centre - a - b,
            self.centre - a + b,
        ]
    }

    /// Half extent of the rectangle's projection onto the unit vector `u`.
    fn radius_along(&self, u: &Vector2<f64>) -> f64 {
        self.half_length * self.axis.dot(u).abs() + self.half_width * self.normal().dot(u).abs()
    }

    /// Whether the two rectangles' interiors overlap (separating axis theorem on the four
    /// edge normals). Rectangles that only touch along an edge or at a corner do not.
    pub fn overlaps(&self, other: &Rect) -> bool {
        let d = other.centre - self.centre;
        let reach =
            self.half_length.hypot(self.half_width) + other.half_length.hypot(other.half_width);
        if d.norm_squared() >= reach * reach {
            return false;
        }
        for u in [self.axis, self.normal(), other.axis, other.normal()] {
            if d.dot(&u).abs() >= self.radius_along(&u) + other.radius_along(&u) {
                return false;
            }
        }
        true
    }
}

fn check_len(name: &str, got: usize, want: usize, shape: &str) -> CoreResult<()> {
    if got == want {
        Ok(())
    } else {
        Err(CoreError::Shape(format!(
            "{name} has {got} values; expected {want} for shape {shape}"
        )))
    }
}

fn check_inputs(traj: &[f64], poses: &[f64], steps: usize, shape: &EgoShape) -> CoreResult<usize> {
    shape.check()?;
    if steps == 0 {
        return Err(CoreError::Shape(
            "trajectories need at least one step (T ≥ 1)".to_owned(),
        ));
    }
    if !traj.len().is_multiple_of(2 * steps) {
        return Err(CoreError::Shape(format!(
            "trajectories have {} values, not a multiple of T·2 = {}",
            traj.len(),
            2 * steps
        )));
    }
    let n = traj.len() / (2 * steps);
    check_len("poses", poses.len(), 3 * n, &format!("({n}, 3)"))?;
    for (f, p) in poses.chunks_exact(3).enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(CoreError::NonFinite {
                what: "pose",
                frame: f,
                step: 0,
            });
        }
    }
    for (i, v) in traj.chunks_exact(2).enumerate() {
        if !(v[0].is_finite() && v[1].is_finite()) {
            return Err(CoreError::NonFinite {
                what: "trajectory",
                frame: i / steps,
                step: i % steps,
            });
        }
    }
    Ok(n)
}

/// The reference points and headings of one frame's trajectory in the global frame:
/// `out[k] = (x, y, θ)` for k = 0..T−1 (step k + 1 of the trajectory).
pub fn frame_poses(traj: &[f64], pose: &[f64], shape: &EgoShape, out: &mut [[f64; 3]]) {
    let iso = Isometry2::new(Vector2::new(pose[0], pose[1]), pose[2]);
    let mut prev = Point2::new(0.0, 0.0);
    let mut heading = 0.0_f64;
    for (k, slot) in out.iter_mut().enumerate() {
        let p = Point2::new(traj[2 * k], traj[2 * k + 1]);
        let step = p - prev;
        if step.norm() >= shape.min_step && step.norm() > 0.0 {
            heading = step.y.atan2(step.x);
        }
        prev = p;
        let g = iso * p;
        *slot = [g.x, g.y, pose[2] + heading];
    }
}

/// The global footprint rectangle at reference pose (x, y, θ).
pub fn footprint(p: &[f64; 3], shape: &EgoShape) -> Rect {
    let (s, c) = p[2].sin_cos();
    Rect::new(
        p[0] + shape.offset * c,
        p[1] + shape.offset * s,
        p[2],
        shape.length,
        shape.width,
    )
}

/// Global (x, y, heading) of every step: (N·T·3) from trajectories (N·T·2) and poses (N·3).
pub fn global_poses(
    traj: &[f64],
    poses: &[f64],
    steps: usize,
    shape: &EgoShape,
) -> CoreResult<Vec<f64>> {
    let n = check_inputs(traj, poses, steps, shape)?;
    let mut out = vec![0.0; n * steps * 3];
    out.par_chunks_mut(steps * 3)
        .zip(traj.par_chunks(steps * 2))
        .zip(poses.par_chunks(3))
        .for_each(|((o, t), p)| {
            let mut buf = vec![[0.0; 3]; steps];
            frame_poses(t, p, shape, &mut buf);
            for (k, v) in buf.iter().enumerate() {
                o[3 * k..3 * k + 3].copy_from_slice(v);
            }
        });
    Ok(out)
}

/// Footprint corners (N·T·4·2), front-left, front-right, rear-right, rear-left.
pub fn footprint_corners(
    traj: &[f64],
    poses: &[f64],
    steps: usize,
    shape: &EgoShape,
) -> CoreResult<Vec<f64>> {
    let g = global_poses(traj, poses, steps, shape)?;
    let mut out = vec![0.0; g.len() / 3 * 8];
    out.par_chunks_mut(8)
        .zip(g.par_chunks(3))
        .for_each(|(o, p)| {
            for (j, c) in footprint(&[p[0], p[1], p[2]], shape)
                .corners()
                .iter()
                .enumerate()
            {
                o[2 * j] = c.x;
                o[2 * j + 1] = c.y;
            }
        });
    Ok(out)
}

/// Overlap of the ego footprint with every agent box: (N·T·A) with 1 where they overlap.
///
/// `agents` is (N·T·A·5): per frame, per step, per agent slot (centre x, centre y, yaw, length,
/// width) in the global frame. A slot whose centre x is NaN is empty (0 in the output); any
/// other non-finite value, or a non-positive size, is refused naming frame, step and slot.
pub fn collisions(
    traj: &[f64],
    poses: &[f64],
    agents: &[f64],
    steps: usize,
    slots: usize,
    shape: &EgoShape,
) -> CoreResult<Vec<u8>> {
    let n = check_inputs(traj, poses, steps, shape)?;
    check_len(
        "agents",
        agents.len(),
        n * steps * slots * BOX_VALUES,
        &format!("({n}, {steps}, {slots}, {BOX_VALUES})"),
    )?;
    for (i, b) in agents.chunks_exact(BOX_VALUES).enumerate() {
        if b[0].is_nan() {
            continue;
        }
        if !b.iter().all(|v| v.is_finite()) || b[3] <= 0.0 || b[4] <= 0.0 {
            let (f, rest) = (i / (steps * slots), i % (steps * slots));
            return Err(CoreError::Argument(format!(
                "agent box at frame {f}, step {}, slot {} is degenerate (centre, yaw, length, width = {:?})",
                rest / slots,
                rest % slots,
                b
            )));
        }
    }
    let mut out = vec![0u8; n * steps * slots];
    if slots == 0 {
        return Ok(out);
    }
    let per_frame = steps * slots;
    out.par_chunks_mut(per_frame * FRAMES_PER_TASK)
        .enumerate()
        .for_each(|(task, o)| {
            let mut buf = vec![[0.0; 3]; steps];
            for (j, of) in o.chunks_mut(per_frame).enumerate() {
                let f = task * FRAMES_PER_TASK + j;
                frame_poses(
                    &traj[f * steps * 2..(f + 1) * steps * 2],
                    &poses[3 * f..3 * f + 3],
                    shape,
                    &mut buf,
                );
                for (k, p) in buf.iter().enumerate() {
                    let ego = footprint(p, shape);
                    let ego_reach = ego.half_length.hypot(ego.half_width);
                    let base = (f * steps + k) * slots;
                    let boxes = &agents[base * BOX_VALUES..(base + slots) * BOX_VALUES];
                    let hits = &mut of[k * slots..(k + 1) * slots];
                    for (b, hit) in boxes.chunks_exact(BOX_VALUES).zip(hits.iter_mut()) {
                        // bounding circles first: most pairs are far apart, and this needs no sin/cos
                        // (a NaN centre, an empty slot, fails the comparison and is skipped too)
                        let (dx, dy) = (b[0] - ego.centre.x, b[1] - ego.centre.y);
                        let reach = ego_reach + 0.5 * (b[3] * b[3] + b[4] * b[4]).sqrt();
                        let near = dx * dx + dy * dy < reach * reach;
                        if !near {
                            continue;
                        }
                        if ego.overlaps(&Rect::new(b[0], b[1], b[2], b[3], b[4])) {
                            *hit = 1;
                        }
                    }
                }
            }
        });
    Ok(out)
}

/// A binary raster in the nuScenes devkit's `MapMask` convention: row-major (H, W) bytes,
/// `foreground` = drivable (255 in the devkit), pixel (px, py) of global (x, y) =
/// (round(x / r), round(−y / r + H)) with NumPy's round (half to even), r the resolution.
pub struct Mask<'a> {
    pub data: &'a [u8],
    pub height: usize,
    pub width: usize,
    pub resolution: f64,
    pub foreground: u8,
}

/// NumPy's `round` (half to even) for |v| < 2⁵¹ by the add-and-subtract-1.5·2⁵² trick (exact under the
/// default rounding mode; the same result as `f64::round_ties_even`, which without SSE4.1 is a slow
/// library call). Larger values are returned as they are (they lie outside any mask).
#[inline]
pub fn round_half_even(v: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2⁵²
    if v.abs() < 2_251_799_813_685_248.0 {
        (v + MAGIC) - MAGIC
    } else {
        v
    }
}

impl Mask<'_> {
    pub fn check(&self) -> CoreResult<()> {
        check_len(
            "mask",
            self.data.len(),
            self.height * self.width,
            &format!("({}, {})", self.height, self.width),
        )?;
        if !(self.resolution.is_finite() && self.resolution > 0.0) {
            return Err(CoreError::Argument(format!(
                "mask resolution must be positive, got {}",
                self.resolution
            )));
        }
        Ok(())
    }

    /// The pixel index of (x, y) in `data`, or `usize::MAX` when the image does not cover it.
    #[inline]
    pub fn index(&self, x: f64, y: f64) -> usize {
        let scale = 1.0 / self.resolution;
        let px = round_half_even(scale * x);
        let py = round_half_even(-scale * y + self.height as f64);
        if !(px >= 0.0 && py >= 0.0 && px < self.width as f64 && py < self.height as f64) {
            return usize::MAX;
        }
        py as usize * self.width + px as usize
    }

    /// `ON`, `OFF` or `OUTSIDE` of a pixel index from [`Mask::index`].
    #[inline]
    pub fn at(&self, index: usize) -> u8 {
        match self.data.get(index) {
            None => OUTSIDE,
            Some(&v) if v == self.foreground => ON,
            Some(_) => OFF,
        }
    }

    /// `ON`, `OFF` or `OUTSIDE` (the point is not covered by the image).
    pub fn lookup(&self, x: f64, y: f64) -> u8 {
        self.at(self.index(x, y))
    }
}

/// Drivable-area polygons with holes: vertices `xy` (V·2), `rings` offsets into vertices
/// (R + 1), `polygons` offsets into rings (P + 1); a polygon's first ring is its exterior,
/// the others its holes. A point is drivable when it lies inside the exterior and outside
/// every hole of at least one polygon (crossing-number test; points exactly on an edge may
/// go either way — a set of measure zero).
pub struct Polygons<'a> {
    pub xy: &'a [f64],
    pub rings: &'a [usize],
    pub polygons: &'a [usize],
}

/// Per-polygon bounding boxes (min x, min y, max x, max y) for a quick reject.
pub struct PolygonIndex<'a> {
    polys: Polygons<'a>,
    bounds: Vec<[f64; 4]>,
    bands: Vec<Option<Bands>>, // per ring
}

/// A ring's edges bucketed into horizontal bands: the crossing test of a point needs only the edges
/// whose y-range holds its y, i.e. those of its band (real drivable areas have rings of 10⁴ vertices).
struct Bands {
    y0: f64,
    y1: f64,
    height: f64,
    offsets: Vec<u32>, // (bands + 1) into edges
    edges: Vec<u32>,   // edge i joins vertex i − 1 (cyclically) to vertex i
}

/// Rings with fewer vertices are scanned whole.
const BAND_MIN_VERTICES: usize = 16;

impl Bands {
    fn new(pts: &[f64]) -> Option<Self> {
        let m = pts.len() / 2;
        if m < BAND_MIN_VERTICES {
            return None;
        }
        let ys = || pts.chunks_exact(2).map(|p| p[1]);
        let (y0, y1) = ys().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
            (a.min(y), b.max(y))
        });
        let count = m / 4;
        let height = (y1 - y0) / count as f64;
        if height.is_nan() || height <= 0.0 {
            return None;
        }
        let band = |y: f64| (((y - y0) / height) as usize).min(count - 1);
        let span = |i: usize| {
            let j = (i + m - 1) % m;
            let (a, b) = (pts[2 * i + 1], pts[2 * j + 1]);
            (band(a.min(b)), band(a.max(b)))
        };
        let mut sizes = vec![0u32; count + 1];
        let mut total = 0usize;
        for i in 0..m {
            let (lo, hi) = span(i);
            for s in &mut sizes[lo + 1..=hi + 1] {
                *s += 1;
            }
            total += hi - lo + 1;
        }
        if total > 16 * m {
            return None; // long edges everywhere: a plain scan is as good
        }
        for b in 0..count {
            sizes[b + 1] += sizes[b];
        }
        let offsets = sizes.clone();
        let mut fill = sizes;
        let mut edges = vec![0u32; total];
        for i in 0..m {
            let (lo, hi) = span(i);
            for slot in &mut fill[lo..=hi] {
                edges[*slot as usize] = i as u32;
                *slot += 1;
            }
        }
        Some(Bands {
            y0,
            y1,
            height,
            offsets,
            edges,
        })
    }
}

impl<'a> PolygonIndex<'a> {
    pub fn new(polys: Polygons<'a>) -> CoreResult<Self> {
        let v = polys.xy.len() / 2;
        if !polys.xy.len().is_multiple_of(2) {
            return Err(CoreError::Shape(
                "polygon vertices must have shape (V, 2)".to_owned(),
            ));
        }
        if !polys.xy.iter().all(|x| x.is_finite()) {
            return Err(CoreError::Argument(
                "polygon vertices must be finite".to_owned(),
            ));
        }
        let monotone = |o: &[usize], last: usize, what: &str| -> CoreResult<()> {
            if o.is_empty()
                || o[0] != 0
                || *o.last().unwrap() != last
                || o.windows(2).any(|w| w[0] > w[1])
            {
                return Err(CoreError::Shape(format!(
                    "{what} offsets must rise from 0 to {last}, got {} values",
                    o.len()
                )));
            }
            Ok(())
        };
        monotone(polys.rings, v, "ring")?;
        monotone(polys.polygons, polys.rings.len() - 1, "polygon")?;
        let mut bounds = Vec::with_capacity(polys.polygons.len() - 1);
        for w in polys.polygons.windows(2) {
            let (a, b) = (
                polys.rings[w[0]],
                if w[1] > w[0] {
                    polys.rings[w[0] + 1]
                } else {
                    polys.rings[w[0]]
                },
            );
            let mut bb = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            for p in polys.xy[2 * a..2 * b].chunks_exact(2) {
                bb = [
                    bb[0].min(p[0]),
                    bb[1].min(p[1]),
                    bb[2].max(p[0]),
                    bb[3].max(p[1]),
                ];
            }
            bounds.push(bb);
        }
        let bands = (0..polys.rings.len() - 1)
            .map(|r| Bands::new(&polys.xy[2 * polys.rings[r]..2 * polys.rings[r + 1]]))
            .collect();
        Ok(PolygonIndex {
            polys,
            bounds,
            bands,
        })
    }

    fn in_ring(&self, ring: usize, x: f64, y: f64) -> bool {
        let pts = &self.polys.xy[2 * self.polys.rings[ring]..2 * self.polys.rings[ring + 1]];
        let m = pts.len() / 2;
        let mut inside = false;
        if let Some(b) = &self.bands[ring] {
            if !(y >= b.y0 && y <= b.y1) {
                return false;
            }
            let k = (((y - b.y0) / b.height) as usize).min(b.offsets.len() - 2);
            for &e in &b.edges[b.offsets[k] as usize..b.offsets[k + 1] as usize] {
                let i = e as usize;
                let j = (i + m - 1) % m;
                let (xi, yi, xj, yj) = (pts[2 * i], pts[2 * i + 1], pts[2 * j], pts[2 * j + 1]);
                if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
                    inside = !inside;
                }
            }
            return inside;
        }
        let mut j = m.wrapping_sub(1);
        for i in 0..m {
            let (xi, yi, xj, yj) = (pts[2 * i], pts[2 * i + 1], pts[2 * j], pts[2 * j + 1]);
            if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
                inside = !inside;
            }
            j = i;
        }
        inside
    }

    /// Whether (x, y) lies in the union of the polygons.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        for (p, bb) in self.bounds.iter().enumerate() {
            if x < bb[0] || x > bb[2] || y < bb[1] || y > bb[3] {
                continue;
            }
            let (r0, r1) = (self.polys.polygons[p], self.polys.polygons[p + 1]);
            if r1 > r0 && self.in_ring(r0, x, y) && !(r0 + 1..r1).any(|h| self.in_ring(h, x, y)) {
                return true;
            }
        }
        false
    }
}

/// Where the drivable area is looked up.
pub enum Area<'a> {
    Mask(Mask<'a>),
    Polygons(PolygonIndex<'a>),
}

impl Area<'_> {
    pub fn lookup(&self, x: f64, y: f64) -> u8 {
        match self {
            Area::Mask(m) => m.lookup(x, y),
            Area::Polygons(p) => {
                if p.contains(x, y) {
                    ON
                } else {
                    OFF
                }
            }
        }
    }
}

/// Drivable-area outcome of the footprint's four corners and its reference point at every
/// step: (N·T·5) of `ON`, `OFF`, `OUTSIDE`.
pub fn footprint_area(
    traj: &[f64],
    poses: &[f64],
    steps: usize,
    shape: &EgoShape,
    area: &Area<'_>,
) -> CoreResult<Vec<u8>> {
    let n = check_inputs(traj, poses, steps, shape)?;
    if let Area::Mask(m) = area {
        m.check()?;
    }
    let mut out = vec![0u8; n * steps * TEST_POINTS];
    out.par_chunks_mut(steps * TEST_POINTS * FRAMES_PER_TASK)
        .enumerate()
        .for_each(|(task, o)| {
            let mut buf = vec![[0.0; 3]; steps];
            // the task's test points first (x, y), then the lookups: for a mask, the independent loads of
            // a tight loop overlap their cache misses (one random 64-byte line each)
            let mut points = Vec::with_capacity(o.len());
            for j in 0..o.len() / (steps * TEST_POINTS) {
                let f = task * FRAMES_PER_TASK + j;
                frame_poses(
                    &traj[f * steps * 2..(f + 1) * steps * 2],
                    &poses[3 * f..3 * f + 3],
                    shape,
                    &mut buf,
                );
                for p in &buf {
                    points.extend(footprint(p, shape).corners().iter().map(|q| (q.x, q.y)));
                    points.push((p[0], p[1]));
                }
            }
            match area {
                Area::Mask(m) => {
                    let idx: Vec<usize> = points.iter().map(|&(x, y)| m.index(x, y)).collect();
                    for (slot, &i) in o.iter_mut().zip(&idx) {
                        *slot = m.at(i);
                    }
                }
                Area::Polygons(_) => {
                    for (slot, &(x, y)) in o.iter_mut().zip(&points) {
                        *slot = area.lookup(x, y);
                    }
                }
            }
        });
    Ok(out)
}

/// Raw mask lookups of global points (M·2) → (M) of `ON`, `OFF`, `OUTSIDE` (for benches and checks).
pub fn mask_points(points: &[f64], mask: &Mask<'_>) -> CoreResult<Vec<u8>> {
    mask.check()?;
    if !points.len().is_multiple_of(2) {
        return Err(CoreError::Shape("points must have shape (M, 2)".to_owned()));
    }
    let mut out = vec![0u8; points.len() / 2];
    out.par_chunks_mut(4096)
        .zip(points.par_chunks(2 * 4096))
        .for_each(|(o, c)| {
            // indices first, then the loads: independent loads in a tight loop overlap their cache misses
            let idx: Vec<usize> = c.chunks_exact(2).map(|p| mask.index(p[0], p[1])).collect();
            for (slot, &i) in o.iter_mut().zip(&idx) {
                *slot = mask.at(i);
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHAPE: EgoShape = EgoShape {
        length: 4.0,
        width: 2.0,
        offset: 1.0,
        min_step: 0.5,
    };

    #[test]
    fn the_default_ego_box_is_lightemmas() {
        let d = EgoShape::default();
        assert_eq!(
            (d.length, d.width, d.offset, d.min_step),
            (4.084, 1.85, 0.943713 + 0.5, 1.0)
        );
        assert!(d.check().is_ok());
    }

    #[test]
    fn footprint_follows_heading_and_offset() {
        // one step 3 m along +y in the ego frame of a pose at (10, 20) facing +x
        let mut out = [[0.0; 3]; 1];
        frame_poses(&[0.0, 3.0], &[10.0, 20.0, 0.0], &SHAPE, &mut out);
        assert!((out[0][0] - 10.0).abs() < 1e-12 && (out[0][1] - 23.0).abs() < 1e-12);
        assert!((out[0][2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let r = footprint(&out[0], &SHAPE);
        // centre 1 m ahead along +y; length 4 along y, width 2 along x
        assert!((r.centre.y - 24.0).abs() < 1e-12);
        let c = r.corners();
        assert!((c[0].x - 9.0).abs() < 1e-12 && (c[0].y - 26.0).abs() < 1e-12); // front-left
        assert!((c[2].x - 11.0).abs() < 1e-12 && (c[2].y - 22.0).abs() < 1e-12);
        // rear-right
    }

    #[test]
    fn short_steps_keep_the_last_heading() {
        let traj = [2.0, 2.0, 2.1, 2.3, 2.1, 5.3];
        let mut out = [[0.0; 3]; 3];
        frame_poses(&traj, &[0.0, 0.0, 0.5], &SHAPE, &mut out);
        let first = 0.5 + std::f64::consts::FRAC_PI_4;
        assert!((out[0][2] - first).abs() < 1e-12);
        assert!(
            (out[1][2] - first).abs() < 1e-12,
            "0.32 m < min_step keeps the heading"
        );
        assert!((out[2][2] - (0.5 + std::f64::consts::FRAC_PI_2)).abs() < 1e-12);
    }

    #[test]
    fn rotated_rectangles_overlap_exactly() {
        let a = Rect::new(0.0, 0.0, 0.0, 4.0, 2.0);
        // axis-aligned bounding boxes overlap but the rotated boxes do not
        let b = Rect::new(3.2, 2.2, std::f64::consts::FRAC_PI_4, 2.0, 1.0);
        assert!(!a.overlaps(&b) && !b.overlaps(&a));
        // a diamond whose tip pokes into the side
        let c = Rect::new(
            0.0,
            1.0 + std::f64::consts::FRAC_1_SQRT_2 - 0.1,
            std::f64::consts::FRAC_PI_4,
            1.0,
            1.0,
        );
        assert!(a.overlaps(&c) && c.overlaps(&a));
        // touching edge to edge is not an overlap
        let d = Rect::new(4.0, 0.0, 0.0, 4.0, 2.0);
        assert!(!a.overlaps(&d));
        let e = Rect::new(3.999, 0.0, 0.0, 4.0, 2.0);
        assert!(a.overlaps(&e));
    }

    #[test]
    fn collisions_mark_frame_step_slot() {
        // frame 0: straight 5 m steps; an agent at step 2 (x = 10 + offset), one absent slot
        let traj = [5.0, 0.0, 10.0, 0.0];
        let poses = [0.0, 0.0, 0.0];
        let nan = f64::NAN;
        let agents = [
            50.0, 0.0, 0.0, 4.0, 2.0, nan, nan, nan, nan, nan, // step 1
            11.0, 1.5, 0.0, 4.0, 2.0, nan, nan, nan, nan,
            nan, // step 2: 0.5 m lateral overlap
        ];
        let out = collisions(&traj, &poses, &agents, 2, 2, &SHAPE).unwrap();
        assert_eq!(out, vec![0, 0, 1, 0]);
        let mut bad = agents;
        bad[3] = 0.0;
        let err = collisions(&traj, &poses, &bad, 2, 2, &SHAPE)
            .unwrap_err()
            .to_string();
        assert!(err.contains("frame 0, step 0, slot 0"), "{err}");
        let err = collisions(&traj, &poses, &agents[..5], 2, 2, &SHAPE)
            .unwrap_err()
            .to_string();
        assert!(err.contains("(1, 2, 2, 5)"), "{err}");
    }

    #[test]
    fn mask_uses_the_devkit_pixel_transform() {
        // 4 × 3 image, resolution 1 m: pixel row py = round(−y + H)
        let data = [
            0, 0, 255, 0, //
            0, 255, 0, 0, //
            255, 0, 0, 0,
        ];
        let m = Mask {
            data: &data,
            height: 3,
            width: 4,
            resolution: 1.0,
            foreground: 255,
        };
        assert_eq!(m.lookup(0.0, 1.0), ON); // px 0, py 2
        assert_eq!(m.lookup(1.2, 1.8), ON); // px 1, py round(1.2) = 1
        assert_eq!(m.lookup(2.0, 3.0), ON); // py 0
        assert_eq!(m.lookup(0.5, 1.0), ON); // px round-half-even(0.5) = 0
        assert_eq!(m.lookup(1.5, 1.0), OFF); // px 2
        assert_eq!(m.lookup(-0.6, 1.0), OUTSIDE);
        assert_eq!(m.lookup(0.0, 0.4), OUTSIDE); // py round(2.6) = 3 = H
        assert_eq!(m.lookup(3.4, 3.0), OFF);
    }

    #[test]
    fn round_half_even_is_numpys_round() {
        for v in [
            0.5,
            1.5,
            2.5,
            -0.5,
            -1.5,
            -2.5,
            3.4999999,
            3.5000001,
            1e6 + 0.5,
            12345.5,
            -0.0,
            7.0,
        ] {
            assert_eq!(round_half_even(v), v.round_ties_even(), "{v}");
        }
        let mut x = -3000.0;
        while x < 3000.0 {
            assert_eq!(round_half_even(x), x.round_ties_even(), "{x}");
            x += 0.0137;
        }
    }

    #[test]
    fn polygons_with_holes() {
        // a 10 × 10 square with a 2 × 2 hole, and a separate triangle
        let xy = [
            0.0, 0.0, 10.0, 0.0, 10.0, 10.0, 0.0, 10.0, // exterior
            4.0, 4.0, 6.0, 4.0, 6.0, 6.0, 4.0, 6.0, // hole
            20.0, 0.0, 30.0, 0.0, 20.0, 10.0, // triangle
        ];
        let rings = [0, 4, 8, 11];
        let polygons = [0, 2, 3];
        let idx = PolygonIndex::new(Polygons {
            xy: &xy,
            rings: &rings,
            polygons: &polygons,
        })
        .unwrap();
        assert!(idx.contains(1.0, 1.0));
        assert!(!idx.contains(5.0, 5.0));
        assert!(idx.contains(21.0, 8.0));
        assert!(!idx.contains(26.0, 8.0));
        assert!(!idx.contains(-1.0, 5.0));
        assert!(PolygonIndex::new(Polygons {
            xy: &xy,
            rings: &[0, 4, 9],
            polygons: &[0, 2]
        })
        .is_err());
    }

    #[test]
    fn banded_rings_agree_with_a_full_scan() {
        // a star-shaped ring of 400 vertices: banded (≥ 16 vertices) against the plain crossing test
        let m = 400;
        let mut xy = Vec::new();
        for i in 0..m {
            let t = i as f64 / m as f64 * std::f64::consts::TAU;
            let r = 10.0 + 3.0 * (7.0 * t).sin();
            xy.extend([r * t.cos(), r * t.sin()]);
        }
        let rings = [0, m];
        let idx = PolygonIndex::new(Polygons {
            xy: &xy,
            rings: &rings,
            polygons: &[0, 1],
        })
        .unwrap();
        assert!(idx.bands[0].is_some());
        let plain = |x: f64, y: f64| {
            let mut inside = false;
            let mut j = m - 1;
            for i in 0..m {
                let (xi, yi, xj, yj) = (xy[2 * i], xy[2 * i + 1], xy[2 * j], xy[2 * j + 1]);
                if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
                    inside = !inside;
                }
                j = i;
            }
            inside
        };
        let (mut a, mut b) = (0.37_f64, 0.71_f64);
        let mut both = [0, 0];
        for _ in 0..20_000 {
            a = (a * 997.0 + 0.123).fract();
            b = (b * 991.0 + 0.456).fract();
            let (x, y) = (30.0 * a - 15.0, 30.0 * b - 15.0);
            let got = idx.contains(x, y);
            assert_eq!(got, plain(x, y), "({x}, {y})");
            both[got as usize] += 1;
        }
        assert!(both[0] > 1000 && both[1] > 1000);
        // vertices exactly at a band boundary and the extremes
        for (x, y) in [(0.0, 13.0), (0.0, -13.0), (13.0, 0.0), (0.0, 0.0)] {
            assert_eq!(idx.contains(x, y), plain(x, y));
        }
    }

    #[test]
    fn footprint_area_tests_corners_and_reference_point() {
        // a road strip |y| < 1.5 m: the reference point stays on it, a corner does not
        let xy = [-100.0, -1.5, 100.0, -1.5, 100.0, 1.5, -100.0, 1.5];
        let idx = PolygonIndex::new(Polygons {
            xy: &xy,
            rings: &[0, 4],
            polygons: &[0, 1],
        })
        .unwrap();
        let area = Area::Polygons(idx);
        let traj = [5.0, 0.0, 10.0, 0.5];
        let out = footprint_area(&traj, &[0.0, 0.0, 0.0], 2, &SHAPE, &area).unwrap();
        assert_eq!(&out[..5], &[ON, ON, ON, ON, ON]); // |y| ≤ 1 at step 1
                                                      // step 2, heading atan(0.5/5) (sin 0.0995, cos 0.995): front-left corner
                                                      // y = 0.5 + 3·sin + cos = 1.79 > 1.5; rear-left y = 0.5 − sin + cos = 1.40; front-right −0.20
        assert_eq!(&out[5..], &[OFF, ON, ON, ON, ON]);
    }

    #[test]
    fn bad_inputs_are_named() {
        let err = global_poses(&[0.0, f64::NAN], &[0.0, 0.0, 0.0], 1, &SHAPE).unwrap_err();
        assert_eq!(
            err,
            CoreError::NonFinite {
                what: "trajectory",
                frame: 0,
                step: 0
            }
        );
        assert!(global_poses(&[0.0, 0.0], &[0.0, 0.0], 1, &SHAPE).is_err());
        let bad = EgoShape {
            width: 0.0,
            ..SHAPE
        };
        assert!(global_poses(&[0.0, 0.0], &[0.0, 0.0, 0.0], 1, &bad).is_err());
    }
}
