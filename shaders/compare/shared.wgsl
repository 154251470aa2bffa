// Shared by the GPU display and metric passes: the error terms of compare/metrics.rs and the
// log10 histogram bins of compare/heatmap.rs (the CPU path uses the same constants).
#define_import_path gilab::compare

// Histogram of log10 values for heatmap ranges: HIST_PER_DECADE bins per decade from HIST_LO.
const HIST_LO: f32 = -16.0;
const HIST_PER_DECADE: f32 = 64.0;
const HIST_BINS: u32 = 1536u;

// log10 as the CPU computes it (f32::log10 rounds the same way within an ulp).
fn log_ten(v: f32) -> f32 {
    return log2(v) * 0.30102999566398120;
}

fn hist_bin(v: f32) -> u32 {
    let b = floor((log_ten(v) - HIST_LO) * HIST_PER_DECADE);
    return u32(clamp(b, 0.0, f32(HIST_BINS - 1u)));
}

// Per-channel error terms against the reference y: (squared error, relative squared error,
// symmetric absolute percentage error), as in compare/metrics.rs.
fn error_terms(x: vec3<f32>, y: vec3<f32>) -> vec3<f32> {
    let d = x - y;
    let sq = d * d;
    let rel = sq / (y * y + vec3<f32>(0.01));
    let smape = abs(d) / (abs(x) + abs(y) + vec3<f32>(0.01));
    return vec3<f32>(sq.x + sq.y + sq.z, rel.x + rel.y + rel.z, smape.x + smape.y + smape.z);
}
