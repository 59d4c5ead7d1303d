//! The `sunsky` emitter's parameters, with Mitsuba 3's names and defaults (its plugin
//! documentation): `turbidity`, `albedo`, `sun_scale`, `sky_scale`, `sun_aperture`,
//! `complex_sun`, `to_world`, and either `sun_direction` or the time and place (`latitude`,
//! `longitude`, `timezone`, `year`, `month`, `day`, `hour`, `minute`, `second`), never both.
//! The model's tables are looked for beside the scene, in the fetched scenes or where
//! `NIS_SUNSKY_DATA` says ([`crate::sunsky::Dataset::find`]).

use glam::{Mat3, Vec3};

use super::dom::error_at;
use super::dom::Element;
use super::props::Props;
use super::{LoadError, LoadResult, Loader};
use crate::geometry::Rgb;
use crate::light::EnvironmentLight;
use crate::spectrum::Role;
use crate::sunsky::{DateTime, Location, SunPosition, SunSky, SunSkyParams, SUN_APERTURE_DEG};

/// The parameters that place the sun by time and location.
const TIME_AND_PLACE: [&str; 9] = [
    "latitude",
    "longitude",
    "timezone",
    "year",
    "month",
    "day",
    "hour",
    "minute",
    "second",
];

fn error(line: usize, message: impl Into<String>) -> LoadError {
    error_at(line, message).into()
}

impl Loader {
    /// A `<emitter type="sunsky">` whose properties are `p`.
    pub(super) fn sunsky(&mut self, c: &Element, p: &Props) -> LoadResult<()> {
        let sun = if p.by_name.contains_key("sun_direction") {
            if let Some(n) = TIME_AND_PLACE.iter().find(|n| p.by_name.contains_key(*n)) {
                return Err(error(
                    c.line,
                    format!("a sunsky takes sun_direction or the time and place ('{n}'), not both"),
                ));
            }
            SunPosition::Direction(p.point("sun_direction", Vec3::Z)?)
        } else {
            let (t, l) = (DateTime::default(), Location::default());
            let int = |name: &'static str, default: i32, lo: i64, hi: i64| -> LoadResult<i32> {
                let v = p.int(name, i64::from(default))?;
                if !(lo..=hi).contains(&v) {
                    return Err(super::out_of_range(c, name, v, &format!("{lo}..={hi}")));
                }
                Ok(v as i32)
            };
            SunPosition::Time {
                time: DateTime {
                    year: int("year", t.year, -4000, 100_000)?,
                    month: int("month", t.month, 1, 12)?,
                    day: int("day", t.day, 1, 31)?,
                    hour: p.float("hour", t.hour)?,
                    minute: p.float("minute", t.minute)?,
                    second: p.float("second", t.second)?,
                },
                location: Location {
                    latitude: p.float("latitude", l.latitude)?,
                    longitude: p.float("longitude", l.longitude)?,
                    timezone: p.float("timezone", l.timezone)?,
                },
            }
        };
        let params = SunSkyParams {
            turbidity: p.float("turbidity", 3.0)?,
            albedo: p.spectrum("albedo", Rgb::splat(0.3), Role::Reflectance)?,
            sun,
            sun_scale: p.float("sun_scale", 1.0)?,
            sky_scale: p.float("sky_scale", 1.0)?,
            sun_aperture: p.float("sun_aperture", SUN_APERTURE_DEG)?,
            complex_sun: p.boolean("complex_sun", false)?,
            to_world: Mat3::from_mat4(p.transform("to_world")?),
        };
        let mut dirs = vec![self.base_dir.clone()];
        dirs.extend(self.search_paths.iter().cloned());
        let data = crate::sunsky::Dataset::find(&dirs).map_err(LoadError::Other)?;
        match SunSky::new(&params, &data).map_err(|e| error(c.line, format!("sunsky: {e}")))? {
            Some(s) => self.environment_map = Some(EnvironmentLight::SunSky(Box::new(s))),
            None => self.warnings.push((
                c.line,
                "the sunsky sends no light (the sun is below the horizon, which darkens the \
                 sky too in Mitsuba 3, or both scales are zero)"
                    .into(),
            )),
        }
        Ok(())
    }
}
