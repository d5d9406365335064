//! WGS84 geodetic coordinates (latitude, longitude, ellipsoidal height) and the local
//! east-north-up plane around an origin, through `map_3d` (geodetic -> ECEF -> ENU, exact
//! formulas in f64: no projection, no small-area approximation).

use anyhow::{bail, Result};
use map_3d::Ellipsoid;

/// A WGS84 position: latitude and longitude in degrees (north and east positive), ellipsoidal
/// height in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geodetic {
    /// Latitude (degrees, north positive).
    pub lat_deg: f64,
    /// Longitude (degrees, east positive).
    pub lon_deg: f64,
    /// Height above the WGS84 ellipsoid (m).
    pub height: f64,
}

impl Geodetic {
    /// Highest ellipsoidal height accepted (m, either sign): a receiver on or near the
    /// Earth; beyond it the local-plane conversion loses all precision.
    pub const MAX_HEIGHT: f64 = 100_000.0;

    /// Checks the ranges: latitude within +-90, longitude within +-180, height within
    /// +-[`Self::MAX_HEIGHT`], all finite.
    pub fn checked(self) -> Result<Self> {
        if !(self.lat_deg.is_finite() && self.lon_deg.is_finite() && self.height.is_finite()) {
            bail!("not finite");
        }
        if self.lat_deg.abs() > 90.0 {
            bail!("latitude {} is outside -90..90 degrees", self.lat_deg);
        }
        if self.lon_deg.abs() > 180.0 {
            bail!("longitude {} is outside -180..180 degrees", self.lon_deg);
        }
        if self.height.abs() > Self::MAX_HEIGHT {
            bail!(
                "height {} m is outside -{max}..{max} m",
                self.height,
                max = Self::MAX_HEIGHT
            );
        }
        Ok(self)
    }
}

impl std::fmt::Display for Geodetic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:.9},{:.9},{:.4}",
            self.lat_deg, self.lon_deg, self.height
        )
    }
}

/// Parses `LAT,LON,H` (degrees, degrees, metres), as `--origin` takes it.
pub fn parse_origin(s: &str) -> Result<Geodetic> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [lat, lon, h] = parts[..] else {
        bail!("--origin `{s}`: expected LAT,LON,H (degrees, degrees, metres ellipsoidal)");
    };
    let num = |v: &str, what: &str| -> Result<f64> {
        v.parse::<f64>()
            .map_err(|_| anyhow::anyhow!("--origin `{s}`: {what} `{v}` is not a number"))
    };
    let g = Geodetic {
        lat_deg: num(lat, "latitude")?,
        lon_deg: num(lon, "longitude")?,
        height: num(h, "height")?,
    };
    g.checked()
        .map_err(|e| anyhow::anyhow!("--origin `{s}`: {e}"))
}

/// The local tangent plane at an origin: x east, y north, z up (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalFrame {
    origin: Geodetic,
}

impl LocalFrame {
    /// The plane tangent to the ellipsoid at `origin`.
    pub fn new(origin: Geodetic) -> Self {
        Self { origin }
    }

    /// The origin.
    pub fn origin(&self) -> Geodetic {
        self.origin
    }

    /// East, north, up (m) of a position.
    pub fn to_enu(&self, p: &Geodetic) -> [f64; 3] {
        let o = &self.origin;
        let (e, n, u) = map_3d::geodetic2enu(
            p.lat_deg.to_radians(),
            p.lon_deg.to_radians(),
            p.height,
            o.lat_deg.to_radians(),
            o.lon_deg.to_radians(),
            o.height,
            Ellipsoid::WGS84,
        );
        [e, n, u]
    }

    /// The position at east, north, up (m).
    pub fn to_geodetic(&self, enu: [f64; 3]) -> Geodetic {
        let o = &self.origin;
        let (lat, lon, h) = map_3d::enu2geodetic(
            enu[0],
            enu[1],
            enu[2],
            o.lat_deg.to_radians(),
            o.lon_deg.to_radians(),
            o.height,
            Ellipsoid::WGS84,
        );
        Geodetic {
            lat_deg: lat.to_degrees(),
            lon_deg: lon.to_degrees(),
            height: h,
        }
    }
}

#[cfg(test)]
mod tests {
    /// Fuzz finding: a `.pos` height of 1e101 m turned every local coordinate into NaN.
    #[test]
    fn heights_beyond_the_earth_are_refused() {
        let at = |height| Geodetic {
            lat_deg: 49.2,
            lon_deg: 16.6,
            height,
        };
        assert!(at(299.9).checked().is_ok());
        assert!(at(-Geodetic::MAX_HEIGHT).checked().is_ok());
        let e = at(2.1e101).checked().unwrap_err().to_string();
        assert!(e.contains("height") && e.contains("100000"), "{e}");
        assert!(at(-1.0e6).checked().is_err());
        assert!(parse_origin("49.2,16.6,1e9").is_err());
    }

    use super::*;

    /// (origin lat, lon, h, point lat, lon, h, east, north, up): ENU computed independently by
    /// the closed-form WGS84 ECEF formulas (N = a / sqrt(1 - e^2 sin^2 lat), the ECEF difference
    /// rotated into the origin's east-north-up) in 50-digit arithmetic (Python mpmath, a
    /// one-off script; a = 6378137 m, f = 1/298.257223563). Points about 1 km from the origin:
    /// both hemispheres, across the antimeridian, and in the Arctic.
    const CASES: [[f64; 9]; 6] = [
        [
            49.2,
            16.6,
            300.0,
            49.209,
            16.6,
            300.0,
            0.0,
            1000.97040367197,
            -0.078616052350343,
        ],
        [
            49.2,
            16.6,
            300.0,
            49.2,
            16.6137,
            300.0,
            998.48052702592,
            0.0903650687749144,
            -0.0780010349838736,
        ],
        [
            49.2,
            16.6,
            300.0,
            49.1936,
            16.5903,
            305.5,
            -707.045195453896,
            -711.755531497576,
            5.42113813420511,
        ],
        [
            -34.6,
            -58.4,
            25.0,
            -34.6064,
            -58.3922,
            20.0,
            715.442741646641,
            -710.003182601401,
            -5.07973814482772,
        ],
        [
            0.5,
            179.995,
            10.0,
            0.5063,
            -179.9987,
            12.0,
            701.286912276054,
            696.620131632125,
            1.92314753262053,
        ],
        [
            78.2,
            15.6,
            0.0,
            78.2071,
            15.6311,
            -3.0,
            709.832778203778,
            792.880518283473,
            -3.08851024700005,
        ],
    ];

    #[test]
    fn enu_against_independent_values_below_a_millimetre() {
        for c in CASES {
            let f = LocalFrame::new(Geodetic {
                lat_deg: c[0],
                lon_deg: c[1],
                height: c[2],
            });
            let p = Geodetic {
                lat_deg: c[3],
                lon_deg: c[4],
                height: c[5],
            };
            let enu = f.to_enu(&p);
            for k in 0..3 {
                // Far below the 1 mm required: f64 rounding of ECEF values of 6.4e6 m.
                assert!((enu[k] - c[6 + k]).abs() < 1e-6, "{c:?}: {enu:?}");
            }
            let back = f.to_geodetic(enu);
            assert!((back.lat_deg - p.lat_deg).abs() < 1e-11, "{back:?}");
            assert!((back.lon_deg - p.lon_deg).abs() < 1e-11, "{back:?}");
            assert!((back.height - p.height).abs() < 1e-6, "{back:?}");
        }
    }

    #[test]
    fn origin_maps_to_zero_and_signs_follow_the_hemisphere() {
        for (lat, lon) in [(49.0, 16.0), (-49.0, 16.0), (49.0, -16.0), (-49.0, -16.0)] {
            let o = Geodetic {
                lat_deg: lat,
                lon_deg: lon,
                height: 100.0,
            };
            let f = LocalFrame::new(o);
            assert!(f.to_enu(&o).iter().all(|v| v.abs() < 1e-9));
            // A step north in latitude is +y, a step east in longitude is +x, anywhere.
            let north = f.to_enu(&Geodetic {
                lat_deg: lat + 1e-4,
                ..o
            });
            let east = f.to_enu(&Geodetic {
                lon_deg: lon + 1e-4,
                ..o
            });
            assert!(north[1] > 11.0 && north[0].abs() < 1e-6, "{north:?}");
            assert!(east[0] > 7.0 && east[1].abs() < 1e-3, "{east:?}");
        }
    }

    #[test]
    fn origin_option() {
        let g = parse_origin("49.2, -16.6,300.5").unwrap();
        assert_eq!((g.lat_deg, g.lon_deg, g.height), (49.2, -16.6, 300.5));
        for bad in [
            "49.2,16.6",
            "91,0,0",
            "0,181,0",
            "a,0,0",
            "0,0,nan",
            "1,2,3,4",
        ] {
            let e = parse_origin(bad).unwrap_err().to_string();
            assert!(e.contains("--origin"), "{bad}: {e}");
        }
    }
}
