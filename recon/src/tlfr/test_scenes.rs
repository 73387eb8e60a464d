//! Synthetic light fields for the tests and the `tlfr` bench: fronto-parallel rectangles moving linearly over the shutter,
//! seen through a thin lens, sampled by jittered (x, y) with random (u, v, t). Each sample is the
//! nearest rectangle hit by its ray (a miss: z = +∞), traced here independently of the
//! reprojection code: the ray from the lens point (a·u, a·v, 0) through the point of the focus
//! plane Z = F that the pixel position (x, y) names.

use super::bounds::ScreenArea;
use super::hierarchy::{reorder, Hierarchy};
use super::lens::LensModel;
use super::query::max_reach;
use super::reprojection::LensTimeSample;
pub use crate::lcg::Lcg;

/// A rectangle [x0, x1] × [y0, y1] (camera space) at depth `z` at t = 0, displaced by `motion`
/// over the shutter, with a constant colour.
#[derive(Clone, Copy, Debug)]
pub struct MovingRect {
    pub x: [f32; 2],
    pub y: [f32; 2],
    pub z: f32,
    pub motion: [f32; 3],
    pub colour: [f32; 3],
}

/// A thin lens: focal length `f` px, principal point at the image centre, lens radius `a`,
/// focus distance `focus`.
#[derive(Clone, Copy, Debug)]
pub struct ThinLens {
    pub f: f32,
    pub a: f32,
    pub focus: f32,
    pub width: u32,
    pub height: u32,
}

impl ThinLens {
    pub fn model(&self) -> LensModel {
        LensModel {
            c1: -self.f * self.a,
            c2: self.f * self.a / self.focus,
            fx: self.f,
            fy: self.f,
            cx: 0.5 * self.width as f32,
            cy: 0.5 * self.height as f32,
        }
    }
}

/// `spp` samples per pixel of `lens`'s image of `rects` (lens and time random per sample; the
/// lens coordinates stay 0 when `lens.a` is 0), with their colours; rays that hit nothing are
/// misses of colour `background`.
pub fn sample_scene(
    lens: &ThinLens,
    rects: &[MovingRect],
    spp: u32,
    background: [f32; 3],
    seed: u64,
) -> (Vec<LensTimeSample>, Vec<[f32; 3]>) {
    sample_scene_shaded(lens, rects, spp, background, seed, |rect, _, _| rect.colour)
}

/// `sample_scene` with view-dependent shading: a hit's colour is `shade(rect, hit, eye)` with
/// `hit` the camera-space (X, Y) of the hit point at depth `rect.z`-plus-motion and `eye` the
/// camera-space (X, Y) of the lens point the ray left from.
pub fn sample_scene_shaded(
    lens: &ThinLens,
    rects: &[MovingRect],
    spp: u32,
    background: [f32; 3],
    seed: u64,
    shade: impl Fn(&MovingRect, [f32; 2], [f32; 2]) -> [f32; 3],
) -> (Vec<LensTimeSample>, Vec<[f32; 3]>) {
    let mut rng = Lcg(seed);
    let (mut samples, mut colours) = (Vec::new(), Vec::new());
    let (cx, cy) = (0.5 * lens.width as f32, 0.5 * lens.height as f32);
    for py in 0..lens.height {
        for px in 0..lens.width {
            for _ in 0..spp {
                let (x, y) = (px as f32 + rng.uniform(), py as f32 + rng.uniform());
                let (u, v) = if lens.a > 0.0 { rng.disk() } else { (0.0, 0.0) };
                let t = rng.uniform();
                let from = [lens.a * u, lens.a * v];
                let target = [(x - cx) / lens.f * lens.focus, (y - cy) / lens.f * lens.focus];
                let mut best: Option<(f32, &MovingRect, [f32; 2])> = None;
                for rect in rects {
                    let depth = rect.z + t * rect.motion[2];
                    if depth <= 1e-4 {
                        continue;
                    }
                    let s = depth / lens.focus;
                    let hit = [from[0] + (target[0] - from[0]) * s, from[1] + (target[1] - from[1]) * s];
                    let (hx, hy) = (hit[0] - t * rect.motion[0], hit[1] - t * rect.motion[1]);
                    let inside = (rect.x[0]..=rect.x[1]).contains(&hx) && (rect.y[0]..=rect.y[1]).contains(&hy);
                    if inside && best.map_or(true, |(d, _, _)| depth < d) {
                        best = Some((depth, rect, hit));
                    }
                }
                let (z, motion, colour) = match best {
                    Some((depth, rect, hit)) => (depth, rect.motion, shade(rect, hit, from)),
                    None => (f32::INFINITY, [0.0; 3], background),
                };
                samples.push(LensTimeSample { x, y, u, v, t, z, motion });
                colours.push(colour);
            }
        }
    }
    (samples, colours)
}

/// A layered scene over a `width` × `height` image: a static wall at depth 8 in two colours (the
/// sky above it is a miss), a
/// plane at depth 3 sliding right, a defocused near card at depth 1.2, and (with
/// `through_camera`) a card moving from depth 1 through the camera plane at t = 0.5.
pub fn layered_scene(width: u32, height: u32, through_camera: bool) -> (ThinLens, Vec<MovingRect>) {
    let lens = ThinLens { f: width as f32, a: 0.06, focus: 3.0, width, height };
    let mut rects = vec![
        MovingRect { x: [-20.0, 0.0], y: [-2.0, 20.0], z: 8.0, motion: [0.0; 3], colour: [0.2, 0.3, 0.9] },
        MovingRect { x: [0.0, 20.0], y: [-2.0, 20.0], z: 8.0, motion: [0.0; 3], colour: [0.9, 0.8, 0.1] },
        MovingRect { x: [-0.9, 0.1], y: [-0.5, 0.4], z: 3.0, motion: [0.15, 0.02, 0.3], colour: [0.1, 0.9, 0.2] },
        MovingRect { x: [0.1, 0.5], y: [-0.3, 0.6], z: 1.2, motion: [-0.02, 0.0, 0.0], colour: [0.9, 0.1, 0.1] },
    ];
    if through_camera {
        rects.push(MovingRect {
            x: [-0.3, 0.05],
            y: [-0.25, 0.1],
            z: 1.0,
            motion: [0.05, 0.0, -2.0],
            colour: [1.0, 1.0, 1.0],
        });
    }
    (lens, rects)
}

/// The hierarchy over `samples` for queries of radius `radius` on a `width` × `height` image,
/// with the samples and `colours` in its order (what `query::Scene` needs).
pub fn indexed(
    samples: &[LensTimeSample],
    colours: &[[f32; 3]],
    lens: &LensModel,
    z_near: f32,
    (width, height): (u32, u32),
    radius: f32,
) -> (Hierarchy, Vec<LensTimeSample>, Vec<[f32; 3]>) {
    let area = ScreenArea { width: width as f32, height: height as f32, max_reach: max_reach(radius) };
    let (hierarchy, order) = Hierarchy::build(samples, lens, z_near, &area);
    (hierarchy, reorder(samples, &order), reorder(colours, &order))
}
