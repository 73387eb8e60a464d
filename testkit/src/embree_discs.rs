//! Embree 3's oriented-disc points holding the splats, with an intersection filter that records
//! every hit and rejects it so that traversal collects every disc along a ray: the second
//! implementation of `DiscBvh::collect_hits` that `recon/tests/ilfr_embree_discs.rs` checks hit for
//! hit and `recon/benches/ilfr_discs.rs` times (docs/ilfr-design.md, "Slice 7"); recon itself does
//! not talk to Embree.

use embree3::{
    BufferUsage, BuildQuality, Device, Format, GeometryKind, HitN, IntersectContext, IntersectContextExt, RayHit, RayN,
    Scene, SoAHit, SoARay, ValidityN,
};
use recon::ilfr::disc::{Disc, Ray};

/// Every (primitive id, t) the filter saw during one query.
pub type Collected = Vec<(u32, f32)>;

/// The Embree scene of the discs. Its only query is [`EmbreeDiscs::collect`], which always passes
/// an `IntersectContextExt<Collected>`: the filter relies on that.
pub struct EmbreeDiscs {
    scene: Scene<'static>,
}

/// The intersection filter: records every hit and rejects it, so that traversal continues.
fn collect_every_hit(rays: RayN, hits: HitN, mut valid: ValidityN, context: &mut IntersectContext, _: Option<&()>) {
    // SAFETY: the geometry carrying this filter is only ever attached to the scene of an
    // `EmbreeDiscs`, whose only query (`collect`) passes an `IntersectContextExt<Collected>`
    // (repr(C), base context first) by exclusive reference; Embree hands that same context to the
    // filter synchronously on the querying thread, so the bytes after the base context are that
    // `Collected`, and nothing else aliases it during the call.
    #[allow(unsafe_code)]
    let out = unsafe { context.ext_mut::<Collected>() };
    for i in 0..hits.len() {
        if valid[i] != 0 {
            out.push((hits.prim_id(i), rays.tfar(i)));
            valid[i] = 0;
        }
    }
}

impl EmbreeDiscs {
    pub fn build(device: &Device, discs: &[Disc], quality: BuildQuality) -> EmbreeDiscs {
        let mut geometry = device.create_geometry(GeometryKind::ORIENTED_DISC_POINT).expect("disc geometry");
        geometry.set_build_quality(quality);
        let mut vertices = geometry
            .set_new_buffer::<[f32; 4]>(BufferUsage::VERTEX, 0, Format::FLOAT4, 16, discs.len())
            .expect("vertex buffer");
        for (v, d) in vertices.iter_mut().zip(discs) {
            *v = [d.centre[0], d.centre[1], d.centre[2], d.radius];
        }
        geometry
            .set_new_buffer::<[f32; 3]>(BufferUsage::NORMAL, 0, Format::FLOAT3, 12, discs.len())
            .expect("normal buffer")
            .iter_mut()
            .zip(discs)
            .for_each(|(n, d)| *n = d.normal);
        geometry.set_intersect_filter_function::<_, ()>(collect_every_hit);
        let geometry = geometry.commit();
        let mut scene = device.create_scene().expect("scene");
        let id = scene.attach_geometry(&geometry);
        assert_eq!(id, 0);
        scene.commit();
        EmbreeDiscs { scene }
    }

    /// New radii (by primitive id) into the vertex buffer, then a recommit.
    #[allow(dead_code)] // the bench's refit; the test does not refit
    pub fn set_radii(&mut self, radii: &[f32]) {
        self.scene
            .with_geometry_buffer_mut::<[f32; 4], _>(0, BufferUsage::VERTEX, 0, |vertices| {
                for (v, r) in vertices.iter_mut().zip(radii) {
                    v[3] = *r;
                }
            })
            .expect("vertex buffer");
        self.scene.update_geometry_buffer(0, BufferUsage::VERTEX, 0);
        self.scene.commit_geometry(0);
        self.scene.commit();
    }

    /// Every disc the ray hits with t in [t_min, t_max], into `context.ext` (cleared first).
    pub fn collect(&self, ray: &Ray, t_min: f32, t_max: f32, context: &mut IntersectContextExt<Collected>) {
        context.ext.clear();
        context.ctx = IntersectContext::incoherent();
        let mut ray_hit = RayHit::from(embree3::Ray::segment(ray.origin, ray.direction, t_min, t_max));
        self.scene.intersect(context, &mut ray_hit);
    }
}
