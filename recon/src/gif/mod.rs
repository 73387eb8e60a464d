//! Filtered path tracing after Bauszat, Eisemann and Magnor 2011 ("Guided Image Filtering for
//! Interactive High-quality Global Illumination") over the guide buffers of one guide ray per
//! pixel centre (`crate::guide`, which the baselines and ILFR's grain filter read too): the guided
//! image filter exact and fast (`guided_filter`), the pipeline
//! that filters the incident indirect light (demodulated by the albedo, `modulation`) with it or a baseline filter (`filtered_indirect`,
//! run as the methods `gif`, `gif-normal`, `gif-grey`, `bilateral`, `atrous`, `atrous-sn`), and
//! the additional eye rays' geometry-aware lookup and composite (`eye_rays`). The baseline
//! filters themselves are in `crate::baselines`.

pub mod eye_rays;
pub mod filtered_indirect;
pub mod guided_filter;
pub mod modulation;
