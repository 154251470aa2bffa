//! The hybrid shift's Jacobian in primary sample space, on the CPU: the formula
//! shaders/restir_pt/shared.wgsl evaluates (`shift_path`), written once here so that tests can
//! check it against finite differences of the shift itself (tests/restir_pt.rs).

use glam::Vec3;

/// Area-measure density of reaching `xr` (normal `nr`) from `from` by a direction drawn with
/// solid-angle pdf `pdf`: pdf · |cos θ_r| / d².
pub fn area_pdf(pdf: f32, from: Vec3, xr: Vec3, nr: Vec3) -> f32 {
    let d = from - xr;
    let dist_sq = d.length_squared();
    pdf * (nr.dot(d) / dist_sq.sqrt()).abs() / dist_sq
}

/// |∂u'/∂u| of the reconnection step: the offset path's y_{r-1} reaches x_r with solid-angle
/// pdf `pdf_offset`, the base path's x_{r-1} with `pdf_base`.
pub fn reconnection_jacobian(
    pdf_offset: f32,
    offset_prev: Vec3,
    pdf_base: f32,
    base_prev: Vec3,
    xr: Vec3,
    nr: Vec3,
) -> f32 {
    area_pdf(pdf_offset, offset_prev, xr, nr) / area_pdf(pdf_base, base_prev, xr, nr)
}

/// The whole hybrid shift: random replay (factor 1) up to x_{r-1}, the reconnection, and — when
/// x_r's own next direction was BSDF-sampled — the ratio of its pdfs under the offset and the
/// base path's incident directions (`None` for an NEE step at x_r, which costs no factor).
pub fn hybrid_jacobian(reconnection: f32, next_pdfs: Option<(f32, f32)>) -> f32 {
    match next_pdfs {
        Some((offset, base)) => reconnection * offset / base,
        None => reconnection,
    }
}
