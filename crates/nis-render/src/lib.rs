//! `nis-render`: a small, correct and fast CPU path tracer for the path-guiding experiments of
//! *Neural Importance Sampling* (Müller et al. 2019, §3.3 of the arXiv report).
//!
//! The layout follows pbrt-v4, one concept per module: [`geometry`] and [`sampling`] (shared
//! math), [`shape`] and [`bvh`] (geometry and its acceleration structure), [`camera`],
//! [`bsdf`] (materials), [`light`] (with [`envmap`] and [`sunsky`], the environments),
//! [`scene`], [`path_tracer`] (path tracing with NEE + MIS),
//! [`render`] (the parallel, deterministic render loop, its training schedule and the combination
//! of passes), [`guiding`] (the interface that path guiding methods implement, and the methods), [`film`] and [`compare`] (images and error metrics), [`xml`]
//! (Mitsuba 3 scenes) and [`scenes`] (the built-in test scenes, themselves Mitsuba XML).
//!
//! ```
//! use nis_render::path_tracer::{PathTracer, Strategy};
//! use nis_render::render::{render, Budget, RenderOptions, Schedule};
//! let mut scene = nis_render::scenes::load("cornell-box").unwrap();
//! scene.camera.set_resolution(8, 8);
//! let options = RenderOptions {
//!     path_tracer: PathTracer::from_scene(&scene, Strategy::Mis),
//!     budget: Budget::Samples(2),
//!     seed: 1,
//!     schedule: Schedule::Plain,
//! };
//! let out = render(&scene, &options, &mut nis_render::guiding::NoGuide, &|_| {});
//! assert_eq!(out.image.pixels.len(), 64);
//! ```

#![warn(missing_docs)]

pub mod bsdf;
pub mod bump;
pub mod bvh;
pub mod camera;
pub mod compare;
pub mod envmap;
pub mod film;
pub mod filter;
pub mod geometry;
pub mod guiding;
pub mod light;
pub mod path_tracer;
pub mod ply;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod scenes;
pub mod serialized;
pub mod shape;
pub mod spectrum;
pub mod sunsky;
pub mod texture;
pub mod xml;

/// Everything that can go wrong while loading, rendering or writing.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file is malformed or uses something unsupported.
    #[error("{file}:{line}: {message}")]
    Xml {
        /// Scene file.
        file: String,
        /// 1-based line of the offending element.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A mesh file named by a scene does not exist.
    #[error("mesh file not found: {path}")]
    MissingMesh {
        /// The path looked for.
        path: String,
    },
    /// A mesh file could not be read.
    #[error("could not load mesh {path}: {message}")]
    Mesh {
        /// The mesh file.
        path: String,
        /// Reason.
        message: String,
    },
    /// Reading a file failed.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Reading or writing an image failed.
    #[error("image {path}: {message}")]
    Image {
        /// The image file.
        path: String,
        /// Reason.
        message: String,
    },
    /// The `sunsky` emitter's tables (Mitsuba's `sunsky_datasets.bin` and `sampling_data.bin`)
    /// are in none of the places looked in.
    #[error(
        "the sunsky emitter needs Mitsuba's tables sunsky_datasets.bin and sampling_data.bin, \
         found in none of: {searched}; fetch them with scripts/scenes/fetch-public-scenes.sh \
         (into data/scenes/mitsuba-data/sunsky/output/) or name their folder in NIS_SUNSKY_DATA"
    )]
    MissingSunskyData {
        /// The folders looked in.
        searched: String,
    },
    /// A `sunsky` table file is not what Mitsuba writes.
    #[error("sunsky table {path}: {message}")]
    SunskyData {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// Invalid input that is not tied to a file.
    #[error("{0}")]
    Invalid(String),
}
