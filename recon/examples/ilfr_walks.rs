//! The cost of one reconstruction ray's walk, single-threaded, per walker, on the gather's own
//! rays of a kept sample file (measurement tool): the paper's all-hits walk with grouping and
//! filter against the nearest-splat walk.
//!
//! ```sh
//! cargo run --release -p recon --example ilfr_walks -- SAMPLES.lfrs RAYS_PER_PIXEL ROUNDS [VIS]
//! ```

use std::time::Instant;

use recon::ilfr::bvh::DiscBvh;
use recon::ilfr::disc::Disc;
use recon::ilfr::filter::SplatShading;
use recon::ilfr::gather::{reconstruction_rays, GatherSettings};
use recon::ilfr::neighbours::KdTree;
use recon::ilfr::reconstruct::{NearestSplat, RayModel, ReconstructStats, Reconstructor, Scratch};
use recon::ilfr::samples::read_indirect;
use recon::ilfr::shrink::{input_rays, scene_diagonal, shrink_splats, ShrinkParams, Trim};
use recon::ilfr::splats::{size_splats_with_juries, GatheredPoints, SplatParams};
use recon::ilfr::surfaces::SurfaceParams;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rays_per_pixel: u32 = args[2].parse().unwrap();
    let rounds: usize = args[3].parse().unwrap();
    let vis: f32 = args.get(4).map_or(0.7, |v| v.parse().unwrap());
    let file = sampleio::SampleFile::open(&args[1]).unwrap();
    let samples = read_indirect(&file).unwrap();
    let storage = GatheredPoints::from_samples(&samples);
    let points = storage.points();
    let tree = KdTree::build(points.position);
    let (sized, _) = size_splats_with_juries(&tree, &points, &SplatParams::default(), None).unwrap();
    let discs: Vec<Disc> =
        (0..points.position.len()).map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k])).collect();
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let rays = input_rays(&samples, &storage.sample_index);
    shrink_splats(&mut bvh, &rays, &ShrinkParams { trim: Trim::Wedges, ..ShrinkParams::default() }).unwrap();
    let diagonal = scene_diagonal(&bvh, &rays);
    let settings = GatherSettings { rays_per_pixel, seed: 1, offset: 1e-4 * diagonal, ..GatherSettings::default() };
    let gather_rays = reconstruction_rays(&samples, &settings);
    let radiance: Vec<[f32; 3]> =
        storage.sample_index.iter().map(|&i| samples.radiance.as_ref().unwrap()[i as usize]).collect();
    let shading = SplatShading { radiance: &radiance, direction: &storage.direction, kappa: None };
    println!("{} splats, {} rays", bvh.len(), gather_rays.len());
    let models: Vec<(&str, RayModel)> = vec![
        ("paper", RayModel::ApparentSurfaces),
        ("nearest-ours", RayModel::NearestSplat(NearestSplat { radiance: &radiance, visibility_scale: vis })),
    ];
    let mut best = vec![f64::INFINITY; models.len()];
    let mut found = vec![0usize; models.len()];
    for _ in 0..rounds {
        for (m, (_, model)) in models.iter().enumerate() {
            let reconstructor = Reconstructor { bvh: &bvh, shading, surfaces: SurfaceParams::default(), model: *model };
            let (mut scratch, mut stats) = (Scratch::default(), ReconstructStats::default());
            let start = Instant::now();
            let mut hits = 0;
            for ray in &gather_rays {
                hits += reconstructor.radiance(ray, &mut scratch, &mut stats).is_some() as usize;
            }
            best[m] = best[m].min(start.elapsed().as_secs_f64());
            found[m] = hits;
        }
    }
    for (m, (name, _)) in models.iter().enumerate() {
        println!(
            "{name:24} {:.3} s  {:.3} µs/ray  {:.1}% found",
            best[m],
            1e6 * best[m] / gather_rays.len() as f64,
            100.0 * found[m] as f64 / gather_rays.len() as f64
        );
    }
}
