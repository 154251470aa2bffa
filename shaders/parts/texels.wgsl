// Texel copies of storage buffers (src/parts/texels.rs, BufferTexels): a pass that reads the
// same records many times reads them from a texture instead, which lavapipe loads several
// times faster than a storage buffer's words. The distance field's and DDGI's copies use rows
// of WIDE_ROW texels (`texels::WIDE_ROW` in Rust).
#define_import_path gilab::texels

// Where element i of a copy with rows of 8192 texels is.
fn wide_texel(i: u32) -> vec2<u32> {
    return vec2<u32>(i & 8191u, i >> 13u);
}
