//! gilab: a research sandbox for real-time global illumination. Several GI techniques render
//! one scene from one camera; each reports rays traced, GPU time per pass and error against a
//! reference path tracer, counted the same way for all. See README.md and shared/DESIGN.md.

pub mod app;
pub mod cli;
pub mod compare;
pub mod experiment;
pub mod gpu;
pub mod jobs;
pub mod parts;
pub mod preset;
pub mod render;
pub mod scene;
pub mod techniques;
