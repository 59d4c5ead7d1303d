//! The built-in scenes, shipped as Mitsuba 3 XML inside the crate so that exactly the same file
//! can be rendered by Mitsuba for comparison (`scripts/scenes/reference-mitsuba.py`).
//!
//! * `cornell-box`: the classic Cornell box (Goral et al. 1984), our own dimensions.
//! * `cornell-indirect`: its light faces the ceiling, so the room is lit only indirectly.
//! * `two-rooms-door`: a dark room lit through a narrow door gap from a second room, the case
//!   that motivates path guiding (cf. Vorba et al. 2014, Müller et al. 2017).
//! * `cornell-glossy`: rough conductors, a glass and a rough glass sphere.
//!
//! Each scene takes the parameters `spp`, `res` (square image side) and `max_depth`.

use crate::scene::Scene;
use crate::xml::load_scene_str;
use crate::Error;

/// `(name, Mitsuba XML)` of every built-in scene.
pub const SCENES: [(&str, &str); 4] = [
    ("cornell-box", include_str!("../scenes/cornell-box.xml")),
    (
        "cornell-indirect",
        include_str!("../scenes/cornell-indirect.xml"),
    ),
    (
        "two-rooms-door",
        include_str!("../scenes/two-rooms-door.xml"),
    ),
    (
        "cornell-glossy",
        include_str!("../scenes/cornell-glossy.xml"),
    ),
];

/// The XML of a built-in scene.
pub fn xml(name: &str) -> Option<&'static str> {
    SCENES.iter().find(|(n, _)| *n == name).map(|(_, x)| *x)
}

/// Names of the built-in scenes.
pub fn names() -> impl Iterator<Item = &'static str> {
    SCENES.iter().map(|(n, _)| *n)
}

/// Load built-in scene `name` with its default parameters.
pub fn load(name: &str) -> Result<Scene, Error> {
    load_with(name, &[])
}

/// Load built-in scene `name`, overriding its `<default>` parameters.
pub fn load_with(name: &str, params: &[(String, String)]) -> Result<Scene, Error> {
    let text = xml(name).ok_or_else(|| {
        Error::Invalid(format!(
            "no built-in scene '{name}' (there are: {})",
            names().collect::<Vec<_>>().join(", ")
        ))
    })?;
    load_scene_str(
        text,
        std::path::Path::new("."),
        &format!("<built-in {name}>"),
        params,
    )
}
