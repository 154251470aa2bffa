//! ReSTIR's lighting core, the part every family that resamples light holds: DI (initial
//! candidates per light class, temporal and spatial reuse), GI (sample paths, their reuse and
//! where they end), ReGIR's camera grid, their shared parameters (`gilab::restir`, bind group
//! 2) and buffers. The `restir` technique is this core plus a shading pass; the direct-light
//! part ([`super::restir_direct`]) and the indirect-light part ([`super::restir_gi`]) hold it
//! for other families. Shaders: shaders/parts/restir/, shared state in `shared.wgsl`.
//!
//! Files: `di.rs`, `gi.rs`, `regir.rs` (the three pieces), `lighting.rs` (their composition),
//! `params.rs` (the parameter table and the GPU uniform).

mod di;
mod gi;
mod lighting;
mod params;
mod regir;

pub use di::RESERVOIR_BYTES;
pub use gi::GI_RESERVOIR_BYTES;
pub use lighting::RestirLighting;
pub use params::{
    CandidateVisibility, GiTerminate, RestirParamsGpu, RestirSettings, MAX_SPATIAL, PARAMS,
};
pub use regir::{REGIR_DIMS, REGIR_SLOT_BYTES};
