//! Everything a run hands back to its user: image files (written
//! atomically), error metrics against a reference image, statistics JSON,
//! and experiment tables and plots. Reads films and statistics;
//! never traces.

pub mod image_io;
pub mod overlay;
pub mod plot;
pub mod quality;
pub mod scale;
pub mod stats;

pub use image_io::{
    DisplayImage, ImageMetrics, compare, read_display_image, write_film, write_image,
};
