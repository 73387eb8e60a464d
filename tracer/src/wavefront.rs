//! Paths traced together as a wavefront: every live path's closest-hit ray is traced, then
//! every hit is shaded, then every shadow ray is traced, and again until all paths end. Each
//! phase runs one kind of work over independent paths, so the vertex data of all hits can be
//! loaded ahead of shading with their cache misses overlapping (`preload_vertices`), which a
//! single path's chain of dependent loads does not allow, and each phase's code stays in the
//! instruction cache: one path at a time runs intersection, shading, BSDF and light sampling
//! in turn and misses it about 30 times a sample (cachegrind, the monkeys), the wavefront
//! about once (docs/compare.md).
//!
//! Each path takes the same steps as `Integrator::trace_ray`, so every path's result is
//! bit-identical to tracing it alone (tested in `render.rs` and `samples/lens_time.rs`).

use crate::accel::Hit;
use crate::integrator::{preload_vertices, Integrator, PathState, RayRecorder, RecordedRay, ShadowTest};

/// The paths of one wavefront and the buffers of its phases, kept from one wavefront to the
/// next by whoever traces many.
#[derive(Default)]
pub struct Wavefront {
    /// The paths: filled by the caller (`Integrator::start_path`), traced to their ends by
    /// [`Wavefront::trace`], read back in the same order.
    pub paths: Vec<PathState>,
    live: Vec<(usize, RecordedRay)>,
    hits: Vec<Option<Hit>>,
    shadows: Vec<(usize, ShadowTest)>,
}

impl Wavefront {
    /// Traces every path of `paths` to its end.
    pub fn trace<R: RayRecorder>(&mut self, integrator: &Integrator, recorder: &mut R) {
        loop {
            self.live.clear();
            for (i, path) in self.paths.iter_mut().enumerate() {
                if let Some(ray) = integrator.next_ray(path, recorder) {
                    self.live.push((i, ray));
                }
            }
            if self.live.is_empty() {
                break;
            }
            self.hits.clear();
            self.hits.extend(
                self.live
                    .iter()
                    .map(|(_, ray)| integrator.accel.intersect(ray.origin, ray.direction, 0.0, ray.t_max, ray.time)),
            );
            self.shadows.clear();
            preload_vertices(integrator.scene, &self.hits);
            for ((i, _), hit) in self.live.iter().zip(&self.hits) {
                if let Some(test) = integrator.shade(&mut self.paths[*i], hit.as_ref(), recorder) {
                    self.shadows.push((*i, test));
                }
            }
            for (i, test) in &self.shadows {
                let occluded = integrator.is_occluded(test);
                integrator.resolve_shadow(&mut self.paths[*i], test, occluded);
            }
        }
    }
}
