//! Where the sun stands for an observer at a place, a date and a time: the algorithm of
//! Blanco-Muriel, Alarcón-Padilla, López-Moratalla and Lara-Coira, "Computing the solar vector"
//! (Solar Energy 70(5), 2001), as Mitsuba 3's `sunsky` evaluates it — in single precision, so
//! that the Julian date, near 2.45 million, keeps quarter days, and the hour enters the
//! sidereal time exactly.

use glam::Vec3;

/// An observer's place (Mitsuba's defaults: Tokyo).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Location {
    /// Degrees north.
    pub latitude: f32,
    /// Degrees east.
    pub longitude: f32,
    /// Hours ahead of UTC.
    pub timezone: f32,
}

impl Default for Location {
    fn default() -> Self {
        Location {
            latitude: 35.6894,
            longitude: 139.6917,
            timezone: 9.0,
        }
    }
}

/// A local date and time (Mitsuba's defaults: 10 July 2010, 15:00).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DateTime {
    /// Year.
    pub year: i32,
    /// Month, 1 to 12.
    pub month: i32,
    /// Day of the month.
    pub day: i32,
    /// Hour, local time.
    pub hour: f32,
    /// Minute.
    pub minute: f32,
    /// Second.
    pub second: f32,
}

impl Default for DateTime {
    fn default() -> Self {
        DateTime {
            year: 2010,
            month: 7,
            day: 10,
            hour: 15.0,
            minute: 0.0,
            second: 0.0,
        }
    }
}

/// The sun's zenith angle θ and azimuth φ (radians) in Mitsuba 3's sky frame, where the sun's
/// direction is `(cos φ sin θ, sin φ sin θ, cos θ)`: z up, φ the solar azimuth (from north,
/// through east) minus π.
pub fn sun_coordinates(t: &DateTime, place: &Location) -> (f32, f32) {
    use std::f32::consts::{PI, TAU};
    // Universal time in decimal hours, and days since noon of 1 January 2000 (UT).
    let dec_hours = t.hour - place.timezone + (t.minute + t.second / 60.0) / 60.0;
    // The Julian day number, in integers that truncate towards zero as C's do (i64: no
    // overflow for any i32 date).
    let (year, month, day) = (i64::from(t.year), i64::from(t.month), i64::from(t.day));
    let a = (month - 14) / 12;
    let jdn = (1461 * (year + 4800 + a)) / 4 + (367 * (month - 2 - 12 * a)) / 12
        - (3 * ((year + 4900 + a) / 100)) / 4
        + day
        - 32075;
    let julian = jdn as f32 - 0.5 + dec_hours / 24.0;
    let n = julian - 2_451_545.0;

    // Ecliptic longitude and obliquity.
    let omega = 2.1429 - 0.001_039_459_4 * n;
    let mean_longitude = 4.895_063 + 0.017_202_79 * n;
    let anomaly = 6.240_06 + 0.017_201_97 * n;
    let ecliptic_longitude =
        mean_longitude + 0.033_416_07 * anomaly.sin() + 0.000_348_94 * (2.0 * anomaly).sin()
            - 0.000_113_4
            - 0.000_020_3 * omega.sin();
    let obliquity = 0.409_092_8 - 6.214e-9 * n + 0.000_039_6 * omega.cos();

    // Right ascension and declination.
    let sin_long = ecliptic_longitude.sin();
    let mut right_ascension = (obliquity.cos() * sin_long).atan2(ecliptic_longitude.cos());
    if right_ascension < 0.0 {
        right_ascension += TAU;
    }
    let declination = (obliquity.sin() * sin_long).asin();

    // Local coordinates.
    let gmst = 6.697_424_4 + 0.065_709_83 * n + dec_hours;
    let lmst = (gmst * 15.0 + place.longitude).to_radians();
    let latitude = place.latitude.to_radians();
    let (sin_lat, cos_lat) = latitude.sin_cos();
    let hour_angle = lmst - right_ascension;
    let cos_ha = hour_angle.cos();
    let mut zenith = (cos_lat * cos_ha * declination.cos() + declination.sin() * sin_lat)
        .clamp(-1.0, 1.0)
        .acos();
    let mut azimuth = (-hour_angle.sin()).atan2(declination.tan() * cos_lat - sin_lat * cos_ha);
    if azimuth < 0.0 {
        azimuth += TAU;
    }
    // Parallax: the observer is on the earth's surface, not at its centre.
    const EARTH_MEAN_RADIUS_KM: f64 = 6371.01;
    const ASTRONOMICAL_UNIT_KM: f64 = 149_597_890.0;
    zenith += (EARTH_MEAN_RADIUS_KM / ASTRONOMICAL_UNIT_KM) as f32 * zenith.sin();
    (zenith, azimuth - PI)
}

/// The unit direction of zenith angle `theta` and azimuth `phi` in a z-up frame.
pub fn spherical_direction(theta: f32, phi: f32) -> Vec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Vec3::new(cp * st, sp * st, ct)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mitsuba 3.9.1's sun directions (`scalar_rgb`), from
    /// `mi.traverse(mi.load_dict({"type": "sunsky", "hour": …, …}))["sun_direction"]` with the
    /// identity `to_world`, in the venv of `scripts/scenes/compare-scenes.py` (no tables
    /// needed: the position is arithmetic). The sunset case (18:54) is the most sensitive.
    #[test]
    fn the_sun_stands_where_mitsuba_puts_it() {
        let tokyo = Location::default();
        let day = DateTime::default();
        let cases = [
            (day, tokyo, [0.05138545, 0.691748, 0.7203085]),
            (
                DateTime { hour: 9.0, ..day },
                tokyo,
                [0.09569518, -0.6147862, 0.7828667],
            ),
            (
                DateTime { hour: 18.9, ..day },
                tokyo,
                [-0.4635738, 0.8860548, 0.002492143],
            ),
            (
                DateTime {
                    year: 2023,
                    month: 12,
                    day: 21,
                    hour: 12.5,
                    minute: 17.0,
                    second: 30.0,
                },
                Location {
                    latitude: 48.14,
                    longitude: 11.58,
                    timezone: 1.0,
                },
                [0.9403942, 0.1431115, 0.3085088],
            ),
            (
                DateTime {
                    year: 1999,
                    month: 3,
                    day: 1,
                    hour: 7.25,
                    ..day
                },
                Location {
                    latitude: -33.87,
                    longitude: 151.21,
                    timezone: 11.0,
                },
                [0.09704876, -0.9899412, 0.1029459],
            ),
        ];
        for (t, place, want) in cases {
            let (theta, phi) = sun_coordinates(&t, &place);
            let got = spherical_direction(theta, phi);
            assert!(
                (got - Vec3::from(want)).length() < 2e-5,
                "{t:?} {place:?}: {got} vs {want:?}"
            );
        }
    }
}
