//! GI techniques, one folder each (with a matching folder under `shaders/`). They meet only at
//! the shared inputs (scene, frame uniforms, G-buffer) and at their linear HDR output.

pub mod reference;
pub mod restir;
