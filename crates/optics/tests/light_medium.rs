//! Lights and the medium: parsing, round trips, radiometry helpers, validation.

use glam::{DVec3, Vec3};
use nimbus_optics::{format_lights, parse_lights, Light, Medium, MediumError};
use proptest::prelude::*;

#[test]
fn parses_the_cli_syntax() {
    assert_eq!(Light::parse_sun("dir=0,0,-1,irradiance=3,2,1").unwrap(), Light::Sun { dir: Vec3::NEG_Z, irradiance: Vec3::new(3.0, 2.0, 1.0), angle: 0.0 });
    assert_eq!(Light::parse_sun("irradiance=3").unwrap(), Light::Sun { dir: Vec3::NEG_Z, irradiance: Vec3::splat(3.0), angle: 0.0 });
    assert_eq!("dir=0,0,-2,irradiance=3".parse::<Light>().unwrap(), Light::Sun { dir: Vec3::NEG_Z, irradiance: Vec3::splat(3.0), angle: 0.0 });
    assert_eq!(
        "pos=1,2.5,-3,intensity=10,20,30".parse::<Light>().unwrap(),
        Light::Point { position: DVec3::new(1.0, 2.5, -3.0), intensity: Vec3::new(10.0, 20.0, 30.0) }
    );
    assert_eq!(" pos = 1, 2, 3 , intensity = 5 ".parse::<Light>().unwrap(), Light::Point { position: DVec3::new(1.0, 2.0, 3.0), intensity: Vec3::splat(5.0) });
    assert_eq!("sun:irradiance=2".parse::<Light>().unwrap(), Light::Sun { dir: Vec3::NEG_Z, irradiance: Vec3::splat(2.0), angle: 0.0 });
    assert_eq!("point:pos=0,0,1".parse::<Light>().unwrap(), Light::Point { position: DVec3::Z, intensity: Vec3::ONE });
    // A non-unit direction is normalised.
    let Light::Sun { dir, .. } = Light::parse_sun("dir=3,0,-4").unwrap() else { panic!() };
    assert!((dir - Vec3::new(0.6, 0.0, -0.8)).length() < 1e-7);
}

#[test]
fn bad_light_syntax_is_a_clear_error() {
    for (bad, needle) in [
        ("dir=1,2", "dir needs 3 numbers, got 2"),
        ("dir=0,0,0", "non-zero"),
        ("irradiance=-1", "irradiance must be finite and >= 0"),
        ("irradiance=1,2", "1 (grey) or 3 (RGB)"),
        ("dir=0,0,-1,pos=1,2,3", "mixes"),
        ("color=1", "expected dir"),
        ("dir=a,b,c", "'a' is not a number"),
        ("dir=0,0,-1,,irradiance=1", "empty value"),
        ("dir=0,0,-1,dir=0,0,1", "dir given twice"),
        ("pos=inf,0,0", "not finite"),
        ("1,2,3", "not of the form key=value"),
        ("", "empty"),
        ("=3", "has no key"),
        ("dir=", "has no value"),
        ("point:intensity=3", "pos=X,Y,Z is required"),
        ("sun:pos=1,2,3", "unknown key 'pos'"),
    ] {
        let err = bad.parse::<Light>().unwrap_err().to_string();
        assert!(err.contains(needle), "'{bad}': {err}");
        assert!(err.contains(&format!("'{}'", bad.trim().trim_start_matches("sun:").trim_start_matches("point:"))), "'{bad}' not quoted: {err}");
    }
}

#[test]
fn lights_round_trip_through_text() {
    let lights = [
        Light::sun(Vec3::new(0.3, -0.1, -1.0), Vec3::new(1.5, 1.25, 0.1)).unwrap(),
        Light::sun(Vec3::new(1.0, 2.0, 3.0), Vec3::splat(7.0)).unwrap(),
        Light::point(DVec3::new(1e7 + 0.1, -3.0, 1.0 / 3.0), Vec3::new(100.0, 0.0, 1e-9)).unwrap(),
    ];
    for l in lights {
        assert_eq!(l.to_string().parse::<Light>().unwrap(), l, "{l}");
    }
    assert_eq!(lights[1].to_string(), format!("dir={},irradiance=7", {
        let Light::Sun { dir, .. } = lights[1] else { unreachable!() };
        dir.to_array().map(|x| x.to_string()).join(",")
    }));
    let text = format_lights(&lights);
    assert_eq!(parse_lights(&text).unwrap(), lights);
    assert!(parse_lights("").unwrap().is_empty());
}

proptest! {
    #[test]
    fn any_sun_round_trips(d in prop::array::uniform3(-1e3f32..1e3), e in prop::array::uniform3(0f32..1e6)) {
        if let Ok(l) = Light::sun(Vec3::from(d), Vec3::from(e)) {
            prop_assert_eq!(l.to_string().parse::<Light>().unwrap(), l);
        }
    }

    #[test]
    fn any_point_round_trips(p in prop::array::uniform3(-1e9f64..1e9), i in prop::array::uniform3(0f32..1e6)) {
        let l = Light::point(DVec3::from(p), Vec3::from(i)).unwrap();
        prop_assert_eq!(l.to_string().parse::<Light>().unwrap(), l);
    }
}

#[test]
fn incident_irradiance_and_direction() {
    let sun = Light::sun(Vec3::new(0.0, 1.0, -1.0), Vec3::splat(2.0)).unwrap();
    let inc = sun.incident(DVec3::new(5.0, 6.0, 7.0));
    assert!((inc.to_light - Vec3::new(0.0, -1.0, 1.0).normalize()).length() < 1e-6);
    assert_eq!(inc.irradiance, Vec3::splat(2.0));
    assert!(inc.distance.is_infinite());

    let point = Light::point(DVec3::new(1.0, 2.0, 3.0), Vec3::new(8.0, 4.0, 2.0)).unwrap();
    let inc = point.incident(DVec3::new(1.0, 2.0, 1.0));
    assert_eq!(inc.to_light, Vec3::Z);
    assert_eq!(inc.distance, 2.0);
    assert_eq!(inc.irradiance, Vec3::new(2.0, 1.0, 0.5));
    assert_eq!(point.irradiance_at(DVec3::new(1.0, 2.0, 3.0)), Vec3::ZERO, "at the light itself");
    assert_eq!(point.direction_to_light(DVec3::new(1.0, 0.0, 3.0)), Vec3::Y);
}

#[test]
fn emitted_power_follows_design_section_5() {
    // A point light emits I times the solid angle (4 pi I into every direction); a sun E
    // times its emitting area.
    let point = Light::point(DVec3::splat(0.5), Vec3::new(1.0, 2.0, 3.0)).unwrap();
    let expected = Vec3::new(1.0, 2.0, 3.0) * 4.0 * std::f32::consts::PI;
    assert!((point.emitted_power(4.0 * std::f64::consts::PI) - expected).length() < 1e-5);
    assert_eq!(point.emitted_power(0.5), Vec3::new(0.5, 1.0, 1.5));
    let sun = Light::sun(Vec3::new(1.0, 0.5, -0.7), Vec3::new(2.0, 1.0, 0.5)).unwrap();
    assert_eq!(sun.emitted_power(3.0), Vec3::new(6.0, 3.0, 1.5));
    assert_eq!(sun.emitted_power(0.0), Vec3::ZERO);
}

#[test]
fn medium_defaults_and_coefficients() {
    let m = Medium::default();
    assert_eq!((m.extinction, m.albedo, m.g), (1.0, Vec3::splat(0.9), 0.0));
    m.validate().unwrap();
    let m = Medium::new(2.0, Vec3::new(0.5, 0.25, 1.0), 0.3).unwrap();
    assert_eq!(m.sigma_t(3.0), 6.0);
    assert_eq!(m.sigma_s(3.0), Vec3::new(3.0, 1.5, 6.0));
    assert!((m.albedo_mean() - 0.583_333_3).abs() < 1e-6);
    assert_eq!(m.phase().g, 0.3);
    assert!(Medium::new(0.0, Vec3::ONE, 0.0).unwrap().is_non_scattering());
    assert!(Medium::new(1.0, Vec3::ZERO, 0.0).unwrap().is_non_scattering());
}

#[test]
fn medium_validation() {
    for (e, a, g, expect) in [
        (-1.0, Vec3::ONE, 0.0, "extinction"),
        (f32::INFINITY, Vec3::ONE, 0.0, "extinction"),
        (f32::NAN, Vec3::ONE, 0.0, "extinction"),
        (1.0, Vec3::new(1.1, 0.5, 0.5), 0.0, "albedo"),
        (1.0, Vec3::new(0.5, -0.01, 0.5), 0.0, "albedo"),
        (1.0, Vec3::new(0.5, 0.5, f32::NAN), 0.0, "albedo"),
        (1.0, Vec3::ONE, 1.0, "g"),
        (1.0, Vec3::ONE, -1.0, "g"),
        (1.0, Vec3::ONE, f32::NAN, "g"),
    ] {
        let err = Medium::new(e, a, g).unwrap_err();
        let ok = matches!(
            (&err, expect),
            (MediumError::Extinction(_), "extinction") | (MediumError::Albedo(_), "albedo") | (MediumError::G(_), "g")
        );
        assert!(ok, "({e}, {a}, {g}): {err}");
    }
    assert!(Medium::new(0.0, Vec3::ZERO, -0.999).is_ok());
    assert!(Medium::new(1e6, Vec3::ONE, 0.999).is_ok());
    assert_eq!(Medium::new(1.0, Vec3::ONE, 1.5).unwrap_err().to_string(), "phase asymmetry g must be in (-1,1), got 1.5");
}

#[test]
fn medium_text_form() {
    let m = Medium::new(2.5, Vec3::new(0.1, 0.2, 0.3), -0.4).unwrap();
    assert_eq!(m.to_string(), "extinction=2.5,albedo=0.1,0.2,0.3,g=-0.4");
    assert_eq!(m.to_string().parse::<Medium>().unwrap(), m);
    assert_eq!(Medium::default().to_string(), "extinction=1,albedo=0.9,g=0");
    assert_eq!("g=0.5".parse::<Medium>().unwrap(), Medium { g: 0.5, ..Medium::default() });
    for (bad, needle) in [("g=1", "(-1,1)"), ("albedo=2", "albedo"), ("extinction=-1", "extinction"), ("sigma=1", "unknown key")] {
        let err = bad.parse::<Medium>().unwrap_err().to_string();
        assert!(err.starts_with("invalid medium") && err.contains(needle), "{bad}: {err}");
    }
}
