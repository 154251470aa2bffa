//! Scripted convergence experiments (`gilab converge`): a preset with an `[experiment]`
//! table names runs (technique entries × sweeps × seeds) and scripted events; each run is
//! rendered frame by frame on the same engine as the viewer and its GPU time, rays and error
//! against a cached reference are recorded after every frame, then summarised as equal-time
//! error, time-to-error, a Pareto front and lag after events.

pub mod plot;
pub mod realtime;
pub mod report;
pub mod rows;
pub mod run;
pub mod spec;
pub mod study;

pub use spec::{CameraKey, Event, ExperimentSettings, Metric, Mode, Shard, Sweep};
