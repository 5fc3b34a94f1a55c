//! # svbrdf-core
//!
//! The pure-Rust core of `svbrdf`: geometry (cameras, the material plane,
//! homographies), reflectance models with analytic derivatives, colour transfer
//! functions, images and the on-disk formats that pipeline stages hand over.
//! Nothing here links OpenCV.
//!
//! ```
//! use svbrdf_core::brdf::{BrdfModel, BrdfParams, LightView, Prepared, Ward};
//! use svbrdf_core::geometry::Vec3;
//!
//! let p = Prepared::new(BrdfParams::default());
//! let obs = LightView::from_points(Vec3::zeros(), Vec3::new(1.4, -0.3, 15.0), Vec3::new(0.0, 0.0, 15.0));
//! let rgb = Ward.radiance(&p, &obs, 400.0);
//! assert!(rgb[0] > 0.0);
//! ```
#![deny(missing_docs)]

pub mod brdf;
pub mod camera_description;
pub mod capture;
pub mod color;
pub mod confidence;
mod error;
pub mod exposure;
pub mod fsutil;
pub mod geometry;
pub mod homography;
pub mod image;
pub mod import;
pub mod maps;
pub mod plane;
pub mod progress;

pub use error::CoreError;
