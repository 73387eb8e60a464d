//! The precompute cache: one file holding a [`Precompute`], keyed by the geometry and the
//! settings it was built from, never by the lights or the albedo (a relight with other lights
//! or materials reuses it bit for bit).
//!
//! Layout (little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `LFRPROBE` |
//! | 4 | format version ([`VERSION`]) |
//! | 32 | SHA-256 of the geometry ([`CacheKey::geometry`]) |
//! | 32 | SHA-256 of the settings ([`CacheKey::settings`]) |
//! | 8 | payload length in bytes |
//! | 32 | SHA-256 of the payload |
//! | … | payload: surfels and their grid, probes, radius, scale, transports, relight table, and the near field's lists when it is on |
//!
//! A file that is not a cache, of another version, truncated, with a wrong checksum or
//! inconsistent contents, or built for other geometry or settings is an error naming the file
//! ([`ProbesError::Cache`]); nothing in it is trusted before the checksum matched, and every
//! index is checked before use. Written through the tracer's atomic writer (a temporary file
//! renamed into place).

use std::collections::HashMap;
use std::path::Path;

use glam::{DVec3, Vec3};
use sha2::{Digest, Sha256};
use tracer::scene::PunctualLight;
use tracer::Scene;

use crate::cpca::{Cluster, Cpca, CpcaSettings, Precision, Values};
use crate::error::CacheProblem;
use crate::geometry::seed_points;
use crate::near_field::NearField;
use crate::placement::CandidateRule;
use crate::precompute::{Precompute, PrecomputeSettings, PrecomputeTimings};
use crate::relight::RelightTable;
use crate::surfels::{Sides, Surfel, SurfelStats, Surfels};
use crate::transport::{Reconstruction, Transport};
use crate::ProbesError;

/// The first bytes of every cache file.
pub const MAGIC: &[u8; 8] = b"LFRPROBE";
/// The format version this build writes and reads; raised whenever the precompute's results
/// change (2: receivers next to a concave edge are no longer hidden; 3: the receivers of hidden
/// sides dropped and the budget spent on the valid sides, `surfels::Sides`; 4: the near field's
/// weights in fp16, 6 B an entry).
pub const VERSION: u32 = 4;
/// Bytes before the payload.
pub const HEADER_BYTES: usize = 8 + 4 + 32 + 32 + 8 + 32;

/// What a cache is keyed by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheKey {
    /// SHA-256 over every mesh's positions, indices, normals, uvs and alpha mask (with its
    /// texels): what rays hit.
    pub geometry: [u8; 32],
    /// SHA-256 over the precompute settings and the flood fill's seed points (the camera and the
    /// positions of the point and spot lights the scene file has: placement reads them, nothing
    /// else of the lights).
    pub settings: [u8; 32],
}

impl CacheKey {
    pub fn of(scene: &Scene, settings: &PrecomputeSettings) -> CacheKey {
        let mut g = Sha256::new();
        g.update(b"geometry");
        g.update((scene.meshes.len() as u64).to_le_bytes());
        for mesh in &scene.meshes {
            g.update((mesh.positions.len() as u64).to_le_bytes());
            for p in &mesh.positions {
                p.to_array().iter().for_each(|v| g.update(v.to_le_bytes()));
            }
            g.update((mesh.indices.len() as u64).to_le_bytes());
            for t in &mesh.indices {
                t.iter().for_each(|v| g.update(v.to_le_bytes()));
            }
            match &mesh.normals {
                Some(normals) => {
                    g.update([1]);
                    for n in normals {
                        n.to_array().iter().for_each(|v| g.update(v.to_le_bytes()));
                    }
                }
                None => g.update([0]),
            }
            match &mesh.uvs {
                Some(uvs) => {
                    g.update([1]);
                    for uv in uvs {
                        uv.to_array().iter().for_each(|v| g.update(v.to_le_bytes()));
                    }
                }
                None => g.update([0]),
            }
            g.update(mesh.motion.to_array().map(f32::to_le_bytes).concat());
            let alpha = scene.materials.get(mesh.material as usize).and_then(|m| m.alpha.as_ref());
            match alpha {
                Some(a) => {
                    g.update([1]);
                    g.update((a.channel as u64).to_le_bytes());
                    g.update(a.factor.to_le_bytes());
                    g.update(a.cutoff.to_le_bytes());
                    g.update(format!("{:?}", a.texture).as_bytes());
                    if let Some(t) = scene.textures.get(a.texture.index as usize) {
                        g.update(t.width.to_le_bytes());
                        g.update(t.height.to_le_bytes());
                        for texel in &t.texels {
                            g.update(texel);
                        }
                    }
                }
                None => g.update([0]),
            }
        }
        let mut s = Sha256::new();
        s.update(b"settings");
        let PrecomputeSettings { surfels, placement, transport, relight_rays } = settings;
        s.update((surfels.budget as u64).to_le_bytes());
        s.update(surfels.samples_per_cell.to_le_bytes());
        s.update(surfels.seed.to_le_bytes());
        s.update([match surfels.sides {
            Sides::All => 0u8,
            Sides::Valid => 1,
            Sides::Seeing => 2,
        }]);
        s.update((placement.probes as u64).to_le_bytes());
        s.update(placement.overlap.to_le_bytes());
        s.update([match placement.rule {
            CandidateRule::FrontFacing => 0u8,
            CandidateRule::Paper => 1,
        }]);
        s.update((transport.order as u64).to_le_bytes());
        s.update(transport.directions.to_le_bytes());
        s.update(transport.seed.to_le_bytes());
        s.update([match transport.reconstruction {
            Reconstruction::VisibilityAware => 0u8,
            Reconstruction::SpatialOnly => 1,
        }]);
        s.update(relight_rays.to_le_bytes());
        let seeds = seed_points(scene);
        s.update((seeds.len() as u64).to_le_bytes());
        for p in seeds {
            p.to_array().iter().for_each(|v| s.update(v.to_le_bytes()));
        }
        // Only when on, so that a precompute without it keeps the key it always had.
        if let Some(near) = transport.near {
            s.update(b"near");
            s.update(near.to_le_bytes());
        }
        CacheKey { geometry: g.finalize().into(), settings: s.finalize().into() }
    }
}

/// Whether any of the scene's lights is a point or spot light (their positions seed the flood
/// fill, so they are part of [`CacheKey::settings`]).
pub fn lights_seed_placement(scene: &Scene) -> bool {
    scene.lights.iter().any(|l| matches!(l, PunctualLight::Point { .. } | PunctualLight::Spot { .. }))
}

fn cache_error(path: &Path, problem: CacheProblem, message: impl Into<String>) -> ProbesError {
    ProbesError::Cache { path: path.to_path_buf(), problem, message: message.into() }
}

/// The bytes of a cache file for `pre` under `key`.
pub fn encode(key: &CacheKey, pre: &Precompute) -> Vec<u8> {
    let mut w = Vec::new();
    let s = &pre.surfels;
    put_f64(&mut w, s.h);
    put_dvec3(&mut w, s.origin);
    let st = &s.stats;
    put_u64(&mut w, st.surfels as u64);
    put_f64(&mut w, st.area);
    put_f64(&mut w, st.h);
    put_u64(&mut w, st.samples as u64);
    put_u64(&mut w, st.triangles as u64);
    put_u64(&mut w, st.degenerate_triangles as u64);
    put_u64(&mut w, st.dropped as u64);
    put_u64(&mut w, s.surfels.len() as u64);
    for x in &s.surfels {
        put_vec3(&mut w, x.position);
        put_vec3(&mut w, x.normal);
        put_f32(&mut w, x.area);
        put_u32(&mut w, x.mesh);
        put_u32(&mut w, x.triangle);
    }
    // Cells sorted by key: the same precompute gives the same bytes.
    let mut cells: Vec<(&[i64; 3], &(u32, u32))> = s.cells.iter().collect();
    cells.sort_unstable();
    put_u64(&mut w, cells.len() as u64);
    for (c, &(a, b)) in cells {
        c.iter().for_each(|v| w.extend_from_slice(&v.to_le_bytes()));
        put_u32(&mut w, a);
        put_u32(&mut w, b);
    }
    put_u64(&mut w, pre.probes.len() as u64);
    pre.probes.iter().for_each(|p| put_dvec3(&mut w, *p));
    put_f64(&mut w, pre.radius);
    put_f64(&mut w, pre.scale);
    put_u64(&mut w, pre.hidden as u64);
    put_u64(&mut w, pre.transports.len() as u64);
    for t in &pre.transports {
        put_u64(&mut w, t.probes.len() as u64);
        t.probes.iter().for_each(|&p| put_u32(&mut w, p));
        put_u64(&mut w, t.alpha.len() as u64);
        t.alpha.iter().for_each(|&a| put_f32(&mut w, a));
        for v in [t.hits, t.unseen, t.escaped, t.back_faces] {
            put_u32(&mut w, v);
        }
    }
    let table = &pre.table;
    put_u32(&mut w, table.rays);
    put_u64(&mut w, table.coefficients as u64);
    put_u64(&mut w, table.sh.len() as u64);
    table.sh.iter().for_each(|&v| put_f32(&mut w, v));
    put_u64(&mut w, table.ranges.len() as u64);
    for (ranges, senders) in table.ranges.iter().zip(&table.senders) {
        put_u64(&mut w, ranges.len() as u64);
        for &(a, b) in ranges {
            put_u32(&mut w, a);
            put_u32(&mut w, b);
        }
        put_u64(&mut w, senders.len() as u64);
        for &(s, wt) in senders {
            put_u32(&mut w, s);
            put_f32(&mut w, wt);
        }
    }
    put_u64(&mut w, table.escaped);
    put_u64(&mut w, table.holes);
    put_u64(&mut w, table.back_face_fraction.len() as u64);
    table.back_face_fraction.iter().for_each(|&v| put_f32(&mut w, v));
    // The near field's lists, only when it is on (a file without it is byte for byte as before).
    if let Some(near) = &pre.near {
        put_u64(&mut w, near.hits);
        put_u64(&mut w, near.holes);
        put_u64(&mut w, near.offsets.len() as u64);
        near.offsets.iter().for_each(|&o| put_u32(&mut w, o));
        put_u64(&mut w, near.entries.len() as u64);
        for &(s, wt) in &near.entries {
            put_u32(&mut w, s);
            w.extend_from_slice(&half::f16::from_f32(wt).to_bits().to_le_bytes());
        }
    }

    frame(MAGIC, key, &w)
}

/// Writes `pre` to `path` under `key`, atomically.
pub fn write(path: &Path, key: &CacheKey, pre: &Precompute) -> Result<(), ProbesError> {
    let bytes = encode(key, pre);
    tracer::output::write_atomically(path, |tmp| std::fs::write(tmp, &bytes).map_err(|e| e.to_string()))
        .map_err(|e| cache_error(path, CacheProblem::Io, format!("cannot write: {e}")))
}

/// Reads the cache at `path`, checking that it was built for `key`; `settings` are those
/// `key` was made from.
pub fn read(path: &Path, key: &CacheKey, settings: &PrecomputeSettings) -> Result<Precompute, ProbesError> {
    let bytes = std::fs::read(path).map_err(|e| cache_error(path, CacheProblem::Io, format!("cannot read: {e}")))?;
    decode(path, &bytes, key, settings)
}

/// [`read`] on bytes already in memory (`path` names them in errors).
pub fn decode(
    path: &Path,
    bytes: &[u8],
    key: &CacheKey,
    settings: &PrecomputeSettings,
) -> Result<Precompute, ProbesError> {
    let payload = unframe(path, bytes, MAGIC, key)?;
    parse(payload, settings).map_err(|why| cache_error(path, CacheProblem::Corrupt, format!("corrupt: {why}")))
}

/// Header and `payload` under `magic` and `key`.
fn frame(magic: &[u8; 8], key: &CacheKey, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_BYTES + payload.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&key.geometry);
    out.extend_from_slice(&key.settings);
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&Sha256::digest(payload));
    out.extend_from_slice(payload);
    out
}

/// The payload of `bytes` after checking magic, version, length, checksum and key.
fn unframe<'a>(path: &Path, bytes: &'a [u8], magic: &[u8; 8], key: &CacheKey) -> Result<&'a [u8], ProbesError> {
    let name = String::from_utf8_lossy(magic);
    if bytes.len() < magic.len() || &bytes[..magic.len()] != magic {
        return Err(cache_error(path, CacheProblem::NotACache, format!("not a probes cache (no {name} magic bytes)")));
    }
    if bytes.len() < HEADER_BYTES {
        return Err(cache_error(
            path,
            CacheProblem::Truncated,
            format!("truncated: {} bytes, shorter than the {HEADER_BYTES}-byte header", bytes.len()),
        ));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    if version != VERSION {
        return Err(cache_error(
            path,
            CacheProblem::Version,
            format!("format version {version}; this build reads version {VERSION} (run `lfr probes precompute` again)"),
        ));
    }
    let length = u64::from_le_bytes(bytes[76..84].try_into().expect("8 bytes"));
    let payload = &bytes[HEADER_BYTES..];
    if (payload.len() as u64) < length {
        return Err(cache_error(
            path,
            CacheProblem::Truncated,
            format!("truncated: the payload has {} of its {length} bytes", payload.len()),
        ));
    }
    if payload.len() as u64 > length {
        return Err(cache_error(
            path,
            CacheProblem::Corrupt,
            format!("corrupt: {} bytes after the {length}-byte payload", payload.len() as u64 - length),
        ));
    }
    if Sha256::digest(payload).as_slice() != &bytes[84..116] {
        return Err(cache_error(path, CacheProblem::Corrupt, "corrupt: the payload's checksum does not match"));
    }
    if bytes[12..44] != key.geometry {
        return Err(cache_error(
            path,
            CacheProblem::OtherGeometry,
            "built for other geometry (the scene's meshes changed); run `lfr probes precompute` again",
        ));
    }
    if bytes[44..76] != key.settings {
        return Err(cache_error(
            path,
            CacheProblem::OtherSettings,
            "built with other settings (receivers, sides, probes, overlap, candidates, order, directions, relight rays, \
             seed, CPCA settings, or the camera and point-light positions that seed the flood fill); run \
             `lfr probes precompute` again",
        ));
    }
    Ok(payload)
}

fn parse(payload: &[u8], settings: &PrecomputeSettings) -> Result<Precompute, String> {
    let mut r = Reader { bytes: payload, pos: 0 };
    let h = r.f64()?;
    let origin = r.dvec3()?;
    let stats = SurfelStats {
        surfels: r.u64()? as usize,
        area: r.f64()?,
        h: r.f64()?,
        samples: r.u64()? as usize,
        triangles: r.u64()? as usize,
        degenerate_triangles: r.u64()? as usize,
        dropped: r.u64()? as usize,
    };
    let n = r.count(36, "surfels")?;
    let mut list = Vec::with_capacity(n);
    for _ in 0..n {
        list.push(Surfel {
            position: r.vec3()?,
            normal: r.vec3()?,
            area: r.f32()?,
            mesh: r.u32()?,
            triangle: r.u32()?,
        });
    }
    let cell_count = r.count(32, "cells")?;
    let mut cells = HashMap::with_capacity(cell_count);
    for _ in 0..cell_count {
        let c = [r.i64()?, r.i64()?, r.i64()?];
        let (a, b) = (r.u32()?, r.u32()?);
        if !(a <= b && b as usize <= n) {
            return Err(format!("cell {c:?} holds surfels {a}..{b} of {n}"));
        }
        cells.insert(c, (a, b));
    }
    let probe_count = r.count(24, "probes")?;
    let mut probes = Vec::with_capacity(probe_count);
    for _ in 0..probe_count {
        probes.push(r.dvec3()?);
    }
    let radius = r.f64()?;
    let scale = r.f64()?;
    let hidden = r.u64()? as usize;
    let nc = (settings.transport.order + 1) * (settings.transport.order + 1);
    let transport_count = r.count(32, "transports")?;
    if transport_count != n {
        return Err(format!("{transport_count} transports for {n} surfels"));
    }
    let mut transports = Vec::with_capacity(transport_count);
    for i in 0..transport_count {
        let np = r.count(4, "transport probes")?;
        let mut tp = Vec::with_capacity(np);
        for _ in 0..np {
            let p = r.u32()?;
            if p as usize >= probe_count || tp.last().is_some_and(|&q| q >= p) {
                return Err(format!("receiver {i}: probe {p} out of order or range ({probe_count} probes)"));
            }
            tp.push(p);
        }
        let na = r.count(4, "transport coefficients")?;
        if na != np * nc {
            return Err(format!("receiver {i}: {na} coefficients for {np} probes of {nc}"));
        }
        let mut alpha = Vec::with_capacity(na);
        for _ in 0..na {
            alpha.push(r.f32()?);
        }
        transports.push(Transport {
            probes: tp,
            alpha,
            hits: r.u32()?,
            unseen: r.u32()?,
            escaped: r.u32()?,
            back_faces: r.u32()?,
        });
    }
    let rays = r.u32()?;
    let coefficients = r.u64()? as usize;
    if coefficients != nc || rays != settings.relight_rays {
        return Err(format!("relight table of {rays} rays and {coefficients} coefficients"));
    }
    let sh_len = r.count(4, "relight SH")?;
    if sh_len != rays as usize * nc {
        return Err(format!("{sh_len} relight SH values for {rays} rays"));
    }
    let mut sh = Vec::with_capacity(sh_len);
    for _ in 0..sh_len {
        sh.push(r.f32()?);
    }
    let table_probes = r.count(16, "relight probes")?;
    if table_probes != probe_count {
        return Err(format!("relight rays of {table_probes} probes for {probe_count} probes"));
    }
    let mut ranges_all = Vec::with_capacity(table_probes);
    let mut senders_all = Vec::with_capacity(table_probes);
    for p in 0..table_probes {
        let nr = r.count(8, "relight ranges")?;
        if nr != rays as usize {
            return Err(format!("probe {p}: {nr} relight rays of {rays}"));
        }
        let mut ranges = Vec::with_capacity(nr);
        for _ in 0..nr {
            ranges.push((r.u32()?, r.u32()?));
        }
        let ns = r.count(8, "relight senders")?;
        if let Some(&(a, b)) = ranges.iter().find(|&&(a, b)| !(a <= b && b as usize <= ns)) {
            return Err(format!("probe {p}: relight range {a}..{b} of {ns} senders"));
        }
        let mut senders = Vec::with_capacity(ns);
        for _ in 0..ns {
            let (s, w) = (r.u32()?, r.f32()?);
            if s as usize >= n {
                return Err(format!("probe {p}: sender {s} of {n} surfels"));
            }
            senders.push((s, w));
        }
        ranges_all.push(ranges);
        senders_all.push(senders);
    }
    let escaped = r.u64()?;
    let holes = r.u64()?;
    let nb = r.count(4, "back-face fractions")?;
    if nb != probe_count {
        return Err(format!("{nb} back-face fractions for {probe_count} probes"));
    }
    let mut back_face_fraction = Vec::with_capacity(nb);
    for _ in 0..nb {
        back_face_fraction.push(r.f32()?);
    }
    let near = match settings.transport.near {
        None => None,
        Some(_) => {
            let (hits, holes) = (r.u64()?, r.u64()?);
            let no = r.count(4, "near-field offsets")?;
            if no != n + 1 {
                return Err(format!("{no} near-field offsets for {n} receivers"));
            }
            let mut offsets = Vec::with_capacity(no);
            for _ in 0..no {
                offsets.push(r.u32()?);
            }
            let ne = r.count(6, "near-field entries")?;
            let mut entries = Vec::with_capacity(ne);
            for _ in 0..ne {
                entries.push((r.u32()?, half::f16::from_bits(r.u16()?).to_f32()));
            }
            let field = NearField { offsets, entries, hits, holes };
            field.check(n)?;
            Some(field)
        }
    };
    if r.pos != payload.len() {
        return Err(format!("{} bytes left over", payload.len() - r.pos));
    }
    let finite = list.iter().all(|s| s.position.is_finite() && s.normal.is_finite())
        && probes.iter().all(|p| p.is_finite())
        && radius.is_finite()
        && radius > 0.0
        && scale.is_finite()
        && h.is_finite()
        && h > 0.0;
    if !finite {
        return Err("non-finite positions, radius or cell size".into());
    }
    Ok(Precompute {
        settings: *settings,
        surfels: Surfels { surfels: list, origin, h, cells, stats },
        probes,
        radius,
        scale,
        transports,
        hidden,
        table: RelightTable {
            rays,
            coefficients,
            sh,
            ranges: ranges_all,
            senders: senders_all,
            escaped,
            holes,
            back_face_fraction,
            fit: None,
        },
        near,
        timings: PrecomputeTimings::default(),
    })
}

/// The first bytes of a compressed-transport (CPCA) cache file.
pub const CPCA_MAGIC: &[u8; 8] = b"LFRPCPCA";

/// The key of the compressed transport of the precompute under `key` with `settings`.
pub fn cpca_key(key: &CacheKey, settings: &CpcaSettings) -> CacheKey {
    let mut s = Sha256::new();
    s.update(b"cpca");
    s.update(key.settings);
    s.update((settings.cluster_limit as u64).to_le_bytes());
    s.update(settings.tolerance.to_le_bytes());
    s.update((settings.max_coefficients as u64).to_le_bytes());
    s.update([u8::from(settings.precision == Precision::F16)]);
    CacheKey { geometry: key.geometry, settings: s.finalize().into() }
}

fn put_values(w: &mut Vec<u8>, v: &Values) {
    put_u64(w, v.len() as u64);
    match v {
        Values::F32(list) => list.iter().for_each(|&x| put_f32(w, x)),
        Values::F16(list) => list.iter().for_each(|x| w.extend_from_slice(&x.to_le_bytes())),
    }
}

/// The bytes of a CPCA cache file for `cpca` under `key` (from [`cpca_key`]).
pub fn encode_cpca(key: &CacheKey, cpca: &Cpca) -> Vec<u8> {
    let mut w = Vec::new();
    put_u64(&mut w, cpca.receivers as u64);
    put_u64(&mut w, cpca.coefficients as u64);
    put_u64(&mut w, cpca.clusters.len() as u64);
    for c in &cpca.clusters {
        put_u64(&mut w, c.receivers.len() as u64);
        c.receivers.iter().for_each(|&r| put_u32(&mut w, r));
        put_u64(&mut w, c.probes.len() as u64);
        c.probes.iter().for_each(|&p| put_u32(&mut w, p));
        put_u64(&mut w, c.rank as u64);
        put_f64(&mut w, c.error);
        put_values(&mut w, &c.u);
        put_values(&mut w, &c.w);
    }
    frame(CPCA_MAGIC, key, &w)
}

/// Writes `cpca` to `path` under `key`, atomically.
pub fn write_cpca(path: &Path, key: &CacheKey, cpca: &Cpca) -> Result<(), ProbesError> {
    let bytes = encode_cpca(key, cpca);
    tracer::output::write_atomically(path, |tmp| std::fs::write(tmp, &bytes).map_err(|e| e.to_string()))
        .map_err(|e| cache_error(path, CacheProblem::Io, format!("cannot write: {e}")))
}

/// Reads the compressed transport of `pre` with `settings` from `path`; `key` from
/// [`cpca_key`]. Every index and size is checked against `pre`.
pub fn read_cpca(path: &Path, key: &CacheKey, settings: &CpcaSettings, pre: &Precompute) -> Result<Cpca, ProbesError> {
    let bytes = std::fs::read(path).map_err(|e| cache_error(path, CacheProblem::Io, format!("cannot read: {e}")))?;
    let payload = unframe(path, &bytes, CPCA_MAGIC, key)?;
    parse_cpca(payload, settings, pre)
        .map_err(|why| cache_error(path, CacheProblem::Corrupt, format!("corrupt: {why}")))
}

fn parse_cpca(payload: &[u8], settings: &CpcaSettings, pre: &Precompute) -> Result<Cpca, String> {
    let mut r = Reader { bytes: payload, pos: 0 };
    let receivers = r.u64()? as usize;
    let coefficients = r.u64()? as usize;
    if receivers != pre.surfels.surfels.len() || coefficients != pre.coefficients() {
        return Err(format!("{receivers} receivers of {coefficients} coefficients for this precompute"));
    }
    let size = match settings.precision {
        Precision::F32 => 4,
        Precision::F16 => 2,
    };
    let count = r.count(32, "clusters")?;
    let mut clusters = Vec::with_capacity(count);
    let mut seen = vec![false; receivers];
    for i in 0..count {
        let n = r.count(4, "cluster receivers")?;
        let mut list = Vec::with_capacity(n);
        for _ in 0..n {
            let x = r.u32()? as usize;
            if x >= receivers || seen[x] {
                return Err(format!("cluster {i}: receiver {x} out of range or in two clusters"));
            }
            seen[x] = true;
            list.push(x as u32);
        }
        let np = r.count(4, "cluster probes")?;
        let mut probes = Vec::with_capacity(np);
        for _ in 0..np {
            let p = r.u32()?;
            if p as usize >= pre.probes.len() {
                return Err(format!("cluster {i}: probe {p} of {}", pre.probes.len()));
            }
            probes.push(p);
        }
        let rank = r.u64()? as usize;
        let error = r.f64()?;
        if rank > settings.max_coefficients || !(error.is_finite() && error >= 0.0) {
            return Err(format!("cluster {i}: rank {rank}, error {error}"));
        }
        let mut values = |expected: usize, what: &str| -> Result<Values, String> {
            let len = r.count(size, what)?;
            if len != expected {
                return Err(format!("cluster {i}: {len} {what} values, expected {expected}"));
            }
            Ok(match settings.precision {
                Precision::F32 => Values::F32((0..len).map(|_| r.f32()).collect::<Result<_, _>>()?),
                Precision::F16 => Values::F16(
                    (0..len).map(|_| r.take::<2>().map(half::f16::from_le_bytes)).collect::<Result<_, _>>()?,
                ),
            })
        };
        let u = values(n * rank, "U")?;
        let w = values(rank * np * coefficients, "W")?;
        clusters.push(Cluster { receivers: list, probes, rank, u, w, error });
    }
    if r.pos != payload.len() {
        return Err(format!("{} bytes left over", payload.len() - r.pos));
    }
    Ok(Cpca { clusters, receivers, coefficients, settings: *settings })
}

fn put_u32(w: &mut Vec<u8>, v: u32) {
    w.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(w: &mut Vec<u8>, v: u64) {
    w.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(w: &mut Vec<u8>, v: f32) {
    w.extend_from_slice(&v.to_le_bytes());
}
fn put_f64(w: &mut Vec<u8>, v: f64) {
    w.extend_from_slice(&v.to_le_bytes());
}
fn put_vec3(w: &mut Vec<u8>, v: Vec3) {
    v.to_array().iter().for_each(|&x| put_f32(w, x));
}
fn put_dvec3(w: &mut Vec<u8>, v: DVec3) {
    v.to_array().iter().for_each(|&x| put_f64(w, x));
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let end = self.pos.checked_add(N).filter(|&e| e <= self.bytes.len()).ok_or("the payload ends early")?;
        let out = self.bytes[self.pos..end].try_into().expect("N bytes");
        self.pos = end;
        Ok(out)
    }
    fn u16(&mut self) -> Result<u16, String> {
        self.take().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Result<u32, String> {
        self.take().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Result<u64, String> {
        self.take().map(u64::from_le_bytes)
    }
    fn i64(&mut self) -> Result<i64, String> {
        self.take().map(i64::from_le_bytes)
    }
    fn f32(&mut self) -> Result<f32, String> {
        self.take().map(f32::from_le_bytes)
    }
    fn f64(&mut self) -> Result<f64, String> {
        self.take().map(f64::from_le_bytes)
    }
    fn vec3(&mut self) -> Result<Vec3, String> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
    fn dvec3(&mut self) -> Result<DVec3, String> {
        Ok(DVec3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    /// A count of items of at least `size` bytes each that must fit in what is left.
    fn count(&mut self, size: usize, what: &str) -> Result<usize, String> {
        let n = self.u64()?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.checked_mul(size as u64).map_or(true, |b| b > left) {
            return Err(format!("{n} {what} do not fit in the {left} bytes left"));
        }
        Ok(n as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpca::{Cpca, CpcaSettings, Precision};
    use crate::frame::{indirect, surfel_albedo};
    use crate::placement::PlacementSettings;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of};
    use crate::transport::TransportSettings;

    fn small_settings() -> PrecomputeSettings {
        PrecomputeSettings {
            surfels: SurfelSettings { budget: 400, ..Default::default() },
            placement: PlacementSettings { probes: 4, overlap: 3.0, ..Default::default() },
            transport: TransportSettings { order: 2, directions: 32, ..Default::default() },
            relight_rays: 200,
        }
    }

    fn small() -> (Scene, PrecomputeSettings, Precompute) {
        let block = tracer::scene::shapes::axis_aligned_box("block", Vec3::splat(0.3), Vec3::splat(0.6), 0);
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), block], Vec3::splat(0.15));
        let settings = small_settings();
        let pre = Precompute::build(&scene, &settings, &mut |_| {}).unwrap();
        (scene, settings, pre)
    }

    #[test]
    fn a_cache_reads_back_bit_for_bit_and_relights_alike() {
        let (scene, settings, pre) = small();
        let key = CacheKey::of(&scene, &settings);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.probes");
        write(&path, &key, &pre).unwrap();
        let back = read(&path, &key, &settings).unwrap();
        assert_eq!(back.surfels.surfels, pre.surfels.surfels);
        assert_eq!(back.surfels.cells, pre.surfels.cells);
        assert_eq!(back.probes, pre.probes);
        assert_eq!(back.transports, pre.transports);
        assert_eq!(back.table.sh, pre.table.sh);
        assert_eq!(back.table.ranges, pre.table.ranges);
        assert_eq!(back.table.senders, pre.table.senders);
        assert_eq!((back.radius, back.scale, back.hidden), (pre.radius, pre.scale, pre.hidden));
        // The same bytes again, and the same relit irradiance.
        assert_eq!(encode(&key, &back), std::fs::read(&path).unwrap());
        let albedo = surfel_albedo(&scene, &pre.surfels);
        let direct: Vec<Vec3> = pre.surfels.surfels.iter().map(|s| Vec3::splat(1.0 + s.position.y)).collect();
        let a = indirect(&pre.transports, &pre.table, &albedo, &direct, 3, 0.0).unwrap();
        let b = indirect(&back.transports, &back.table, &albedo, &direct, 3, 0.0).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn the_key_follows_geometry_and_settings_not_lights_or_albedo() {
        let (scene, settings, _) = small();
        let key = CacheKey::of(&scene, &settings);
        // Lights (a sun, the environment) and materials do not change the key.
        let mut lit = scene.clone();
        lit.add_sun(Vec3::new(0.3, 1.0, 0.2), Vec3::splat(3.0));
        lit.environment = Vec3::splat(0.7);
        lit.materials[0].base_color = Vec3::new(0.1, 0.9, 0.2);
        lit.materials[0].emission = Vec3::splat(4.0);
        assert_eq!(CacheKey::of(&lit, &settings), key);
        // Geometry does.
        let mut moved = scene.clone();
        moved.meshes[1].positions[0].x += 1e-3;
        let k = CacheKey::of(&moved, &settings);
        assert_ne!(k.geometry, key.geometry);
        assert_eq!(k.settings, key.settings);
        // Every setting does.
        let mut other = settings;
        other.transport.directions += 1;
        assert_ne!(CacheKey::of(&scene, &other).settings, key.settings);
        let mut other = settings;
        other.placement.probes += 1;
        assert_ne!(CacheKey::of(&scene, &other).settings, key.settings);
        let mut other = settings;
        other.relight_rays += 1;
        assert_ne!(CacheKey::of(&scene, &other).settings, key.settings);
        // A point light's position seeds the flood fill: it is part of the key.
        let mut point = scene.clone();
        point.lights.push(PunctualLight::Point { position: Vec3::splat(0.8), intensity: Vec3::ONE });
        assert!(lights_seed_placement(&point));
        assert_ne!(CacheKey::of(&point, &settings).settings, key.settings);
    }

    #[test]
    fn corrupt_truncated_foreign_and_stale_caches_are_errors_naming_the_file() {
        let (scene, settings, pre) = small();
        let key = CacheKey::of(&scene, &settings);
        let dir = tempfile::tempdir().unwrap();
        let good = encode(&key, &pre);
        let check = |name: &str, bytes: &[u8], key: &CacheKey, problem: CacheProblem, needle: &str| {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            let err = read(&path, key, &settings).err().unwrap_or_else(|| panic!("{name} was accepted"));
            let message = err.to_string();
            assert!(message.contains(path.to_str().unwrap()), "{name}: {message}");
            assert!(message.contains(needle), "{name}: {message}");
            match err {
                ProbesError::Cache { problem: p, .. } => assert_eq!(p, problem, "{name}: {message}"),
                other => panic!("{name}: {other}"),
            }
        };
        // One flipped bit anywhere in the payload.
        for at in [HEADER_BYTES, HEADER_BYTES + good.len() / 3, good.len() - 1] {
            let mut bad = good.clone();
            bad[at] ^= 0x10;
            check("flipped.probes", &bad, &key, CacheProblem::Corrupt, "checksum");
        }
        // Truncated in the payload and in the header; an empty file.
        check("short.probes", &good[..good.len() - 100], &key, CacheProblem::Truncated, "truncated");
        check("header.probes", &good[..40], &key, CacheProblem::Truncated, "truncated");
        check("empty.probes", &[], &key, CacheProblem::NotACache, "not a probes cache");
        let mut long = good.clone();
        long.push(0);
        check("long.probes", &long, &key, CacheProblem::Corrupt, "after the");
        // Another file entirely; a future version.
        check("other.probes", b"P6\n2 2\n255\n............", &key, CacheProblem::NotACache, "not a probes cache");
        let mut future = good.clone();
        future[8..12].copy_from_slice(&(VERSION + 1).to_le_bytes());
        check("future.probes", &future, &key, CacheProblem::Version, "version");
        // Built for other geometry or settings.
        let mut moved = scene.clone();
        moved.meshes[0].positions[0].y -= 1e-2;
        check("geometry.probes", &good, &CacheKey::of(&moved, &settings), CacheProblem::OtherGeometry, "geometry");
        let mut other = settings;
        other.surfels.seed = 9;
        check("settings.probes", &good, &CacheKey::of(&scene, &other), CacheProblem::OtherSettings, "settings");
        let mut sides = settings;
        sides.surfels.sides = Sides::All;
        check("sides.probes", &good, &CacheKey::of(&scene, &sides), CacheProblem::OtherSettings, "settings");
        // A payload with a matching checksum but an index out of range (a crafted file).
        let mut crafted = pre.clone();
        crafted.transports.iter_mut().find(|t| !t.probes.is_empty()).unwrap().probes[0] = 99;
        check("crafted.probes", &encode(&key, &crafted), &key, CacheProblem::Corrupt, "probe 99");
        // A missing file.
        let missing = dir.path().join("missing.probes");
        let message = read(&missing, &key, &settings).err().unwrap().to_string();
        assert!(message.contains("missing.probes") && message.contains("cannot read"), "{message}");
    }

    #[test]
    fn a_compressed_transport_reads_back_equal_and_a_damaged_or_other_one_is_refused() {
        let (scene, settings, pre) = small();
        let key = CacheKey::of(&scene, &settings);
        let dir = tempfile::tempdir().unwrap();
        let positions: Vec<Vec3> = pre.surfels.surfels.iter().map(|s| s.position).collect();
        for precision in [Precision::F32, Precision::F16] {
            let cs = CpcaSettings { cluster_limit: 64, max_coefficients: 6, precision, ..Default::default() };
            let cpca = Cpca::build(&pre.transports, &positions, pre.coefficients(), &cs).unwrap();
            assert!(cpca.clusters.len() > 1);
            let ckey = cpca_key(&key, &cs);
            let path = dir.path().join("c.cpca");
            write_cpca(&path, &ckey, &cpca).unwrap();
            assert_eq!(read_cpca(&path, &ckey, &cs, &pre).unwrap(), cpca);
            // Other CPCA settings, a flipped bit, a precompute cache in its place: refused, named.
            let other = CpcaSettings { tolerance: 0.01, ..cs };
            let err = read_cpca(&path, &cpca_key(&key, &other), &other, &pre).unwrap_err().to_string();
            assert!(err.contains("c.cpca") && err.contains("other settings"), "{err}");
            let mut bytes = std::fs::read(&path).unwrap();
            let at = bytes.len() - 3;
            bytes[at] ^= 4;
            std::fs::write(&path, &bytes).unwrap();
            let err = read_cpca(&path, &ckey, &cs, &pre).unwrap_err().to_string();
            assert!(err.contains("checksum"), "{err}");
            std::fs::write(&path, encode(&key, &pre)).unwrap();
            let err = read_cpca(&path, &ckey, &cs, &pre).unwrap_err().to_string();
            assert!(err.contains("not a probes cache"), "{err}");
        }
    }
}
