//! What every reconstruction is measured against: the per-pixel average of its input samples
//! (`box_filter`, the method `box`), the edge-aware filters the papers compare with
//! (`bilateral`, the cross-bilateral filter; `atrous`, edge-avoiding À-Trous), and the peer a
//! user would pick instead, Intel Open Image Denoise (`oidn`, through `crate::python`).

pub mod atrous;
pub mod bilateral;
pub mod box_filter;
pub mod oidn;
