//! The render client (`vemlight view`, feature `render`): a scene lit by the streamed lights, with one
//! shadow map per light or per cluster of lights (DESIGN.md, last stage; ALGORITHMS.md §6).
//!
//! Input: [`Light`](crate::lights::Light)s and a [`scene::Scene`]. Output: frames, in a window or
//! as PNGs. The modules form a one-way tree; each uses only modules listed before it:
//!
//! - leaves: [`gpu`] (the device), [`cluster`] (which lights share a shadow map), [`tonemap`] and
//!   [`overlay`] (the display passes);
//! - [`scene`]: meshes, materials, the camera, the normal bins and the scene's device buffers;
//! - [`shadow`]: the shadow-map array of the light groups (uses `scene`, `cluster`, `gpu`);
//! - [`shading`]: the geometry and lighting passes, with per-draw light culling (uses `scene`,
//!   `shadow`, `cluster`);
//! - [`renderer`]: owns every pass and draws one frame ([`Renderer`]);
//! - [`view`]: the client app — arguments, light feeds, the light budget, and the headless, window
//!   and bench frame loops.
//!
//! The client takes the wire format from [`crate::lightset`] and imports nothing of the server or
//! the capture daemon.

pub mod cluster;
pub mod gpu;
pub mod overlay;
pub mod renderer;
pub mod scene;
pub mod shading;
pub mod shadow;
pub mod tonemap;
pub mod view;

pub use renderer::{FrameStats, OUTPUT_FORMAT, Options, Renderer, TARGET_FORMATS, auto_exposure};
