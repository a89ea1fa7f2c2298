//! The pinhole camera: orientation, rays, projection, default framing, text form.

use glam::{DVec2, DVec3};
use nimbus_optics::{Camera, CameraError};
use proptest::prelude::*;

fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
    (a - b).length() < tol
}

#[test]
fn centre_pixel_looks_at_the_target() {
    let cam = Camera::new(DVec3::new(1.0, -5.0, 2.0), DVec3::new(0.5, 3.0, 1.0), DVec3::Z, 55.0, 640, 480).unwrap();
    let (origin, dir) = cam.ray(320.0, 240.0);
    assert_eq!(origin, cam.eye());
    assert!(close(dir, (cam.look_at() - cam.eye()).normalize(), 1e-12));
    let q = cam.project(cam.look_at()).unwrap();
    assert!((q - DVec2::new(320.0, 240.0)).length() < 1e-9, "{q}");
    // Points on the line of sight all project to the centre.
    assert!((cam.project(cam.eye() + 100.0 * cam.forward()).unwrap() - DVec2::new(320.0, 240.0)).length() < 1e-9);
}

/// Pixel (0,0) is top-left with Z up: looking along +Y with up +Z, image right is +X
/// (cross(Y, Z) = X), so the top-left corner ray points to -X and +Z.
#[test]
fn pixel_zero_is_top_left_with_z_up() {
    let cam = Camera::new(DVec3::new(0.0, -10.0, 0.0), DVec3::ZERO, DVec3::Z, 90.0, 200, 100).unwrap();
    assert!(close(cam.right(), DVec3::X, 1e-12));
    assert!(close(cam.image_up(), DVec3::Z, 1e-12));
    let (_, d) = cam.ray(0.0, 0.0);
    assert!(d.x < 0.0 && d.z > 0.0 && d.y > 0.0, "top-left ray {d}");
    // Exact corner directions: tan(45 deg) = 1 horizontally, aspect 1/2 vertically.
    assert!(close(d, DVec3::new(-1.0, 1.0, 0.5).normalize(), 1e-12), "{d}");
    let (_, d) = cam.ray(200.0, 100.0);
    assert!(close(d, DVec3::new(1.0, 1.0, -0.5).normalize(), 1e-12), "bottom-right {d}");
    // A point up and to the right lands in the top-right quadrant.
    let q = cam.project(DVec3::new(1.0, 0.0, 1.0)).unwrap();
    assert!(q.x > 100.0 && q.y < 50.0, "{q}");
    // Behind the eye: not projected, not seen.
    assert!(cam.project(DVec3::new(0.0, -20.0, 0.0)).is_none());
    assert!(!cam.sees(DVec3::new(0.0, -20.0, 0.0)));
}

#[test]
fn project_inverts_ray() {
    let cam = Camera::new(DVec3::new(3.0, 4.0, 5.0), DVec3::new(-1.0, 0.5, 0.0), DVec3::new(0.1, 0.0, 1.0), 35.0, 960, 540).unwrap();
    for &(px, py) in &[(0.0, 0.0), (959.5, 0.5), (480.0, 270.0), (12.25, 500.75), (960.0, 540.0)] {
        let (o, d) = cam.ray(px, py);
        assert!((d.length() - 1.0).abs() < 1e-12);
        let q = cam.project(o + 7.5 * d).unwrap();
        assert!((q - DVec2::new(px, py)).length() < 1e-7, "({px},{py}) -> {q}");
    }
}

fn corners(min: DVec3, max: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|i| DVec3::new(if i & 1 == 0 { min.x } else { max.x }, if i & 2 == 0 { min.y } else { max.y }, if i & 4 == 0 { min.z } else { max.z }))
}

/// The default camera sees all 8 corners of the box, for wide, tall, deep, flat and
/// off-origin boxes, and frames it tightly (some corner reaches 85% of the way to an edge).
#[test]
fn default_camera_frames_the_whole_box() {
    let boxes = [
        (DVec3::splat(-1.0), DVec3::splat(1.0)),
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(10.0, 1.0, 1.0)),
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 1.0, 10.0)),
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 30.0, 1.0)),
        (DVec3::new(1e5, -3e5, 42.0), DVec3::new(1e5 + 4.0, -3e5 + 2.0, 45.0)),
        (DVec3::new(-2.0, 0.0, -2.0), DVec3::new(2.0, 0.0, 2.0)),
    ];
    for (min, max) in boxes {
        let cam = Camera::default_for_bounds(min, max).unwrap();
        assert_eq!((cam.width(), cam.height(), cam.fov_deg()), (960, 540, 40.0));
        assert!(close(cam.look_at(), 0.5 * (min + max), 1e-9));
        assert!(close(cam.forward(), DVec3::Y, 1e-12), "looks from -Y");
        assert!(close(cam.image_up(), DVec3::Z, 1e-12), "Z up");
        let mut reach: f64 = 0.0;
        for c in corners(min, max) {
            assert!(cam.sees(c), "box {min}..{max}: corner {c} not in view");
            let q = cam.project(c).unwrap();
            reach = reach.max((q.x / 480.0 - 1.0).abs()).max((q.y / 270.0 - 1.0).abs());
        }
        assert!(reach > 0.85 && reach <= 1.0, "box {min}..{max}: framed loosely ({reach})");
    }
    // A point box still gets a usable camera.
    assert!(Camera::default_for_bounds(DVec3::ONE, DVec3::ONE).unwrap().sees(DVec3::ONE));
}

#[test]
fn degenerate_cameras_are_errors() {
    let e = DVec3::new(0.0, -5.0, 0.0);
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Y, 40.0, 10, 10), Err(CameraError::UpParallelToForward(_))));
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::ZERO, 40.0, 10, 10), Err(CameraError::UpParallelToForward(_))));
    assert!(matches!(Camera::new(e, e, DVec3::Z, 40.0, 10, 10), Err(CameraError::EyeAtLookAt)));
    for fov in [0.0, 180.0, -5.0, f64::NAN, 200.0] {
        assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, fov, 10, 10), Err(CameraError::Fov(_))), "fov {fov}");
    }
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, 0, 10), Err(CameraError::Size(0, 10))));
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, 10, 0), Err(CameraError::Size(10, 0))));
    // Sizes whose pixel buffers cannot exist are refused rather than overflowing later.
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, u32::MAX, u32::MAX), Err(CameraError::TooLarge(..))));
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, 40_000, 1), Err(CameraError::TooLarge(..))));
    assert!(matches!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, 20_000, 20_000), Err(CameraError::TooLarge(..))));
    assert!(Camera::new(e, DVec3::ZERO, DVec3::Z, 40.0, 7680, 4320).is_ok(), "8K is fine");
    assert!(matches!(Camera::new(DVec3::NAN, DVec3::ZERO, DVec3::Z, 40.0, 10, 10), Err(CameraError::NotFinite)));
    assert!(matches!(Camera::default_for_bounds(DVec3::ONE, DVec3::ZERO), Err(CameraError::Bounds(..))));
    assert!(matches!(Camera::default_for_bounds(DVec3::ZERO, DVec3::INFINITY), Err(CameraError::Bounds(..))));
    let msg = Camera::new(e, DVec3::ZERO, DVec3::Y, 40.0, 10, 10).unwrap_err().to_string();
    assert!(msg.contains("parallel"), "{msg}");
}

#[test]
fn sees_sphere_is_conservative() {
    let cam = Camera::new(DVec3::new(0.0, -10.0, 0.0), DVec3::ZERO, DVec3::Z, 60.0, 300, 200).unwrap();
    let mut seen_only_by_sphere = 0;
    for i in -20..=20 {
        for k in -20..=20 {
            for j in [-12.0, -9.0, 0.0, 30.0] {
                let p = DVec3::new(i as f64, j, k as f64);
                if cam.sees(p) {
                    assert!(cam.sees_sphere(p, 0.0) && cam.sees_sphere(p, 1.0), "{p}");
                } else if cam.sees_sphere(p, 0.5) {
                    seen_only_by_sphere += 1;
                }
            }
        }
    }
    assert!(seen_only_by_sphere > 0, "the margin never mattered");
    assert!(!cam.sees_sphere(DVec3::new(100.0, 0.0, 0.0), 1.0));
    assert!(!cam.sees_sphere(DVec3::new(0.0, -15.0, 0.0), 1.0));
    assert!(cam.sees_sphere(DVec3::new(0.0, -10.5, 0.0), 1.0), "sphere around the eye");
}

#[test]
fn text_form_round_trips_and_reports_errors() {
    let cam = Camera::new(DVec3::new(0.1, -7.25, 1e-3), DVec3::new(1.0 / 3.0, 0.0, 2.0), DVec3::new(0.0, 0.2, 1.0), 27.5, 1280, 720).unwrap();
    let text = cam.to_string();
    assert_eq!(text.parse::<Camera>().unwrap(), cam, "{text}");
    let parsed: Camera = "eye=0,-10,1,look_at=0,0,1".parse().unwrap();
    assert_eq!((parsed.fov_deg(), parsed.width(), parsed.height(), parsed.up()), (40.0, 960, 540, DVec3::Z));
    let parsed: Camera = "eye=0,-10,1, look-at=0,0,1, size=320x200".parse().unwrap();
    assert_eq!((parsed.width(), parsed.height()), (320, 200));
    for (bad, needle) in [
        ("look-at=0,0,0", "eye"),
        ("eye=0,-1,0", "look-at"),
        ("eye=0,-1,look-at=0,0,0", "eye needs 3"),
        ("eye=0,-1,0,look-at=0,0,0,fov=190", "fov"),
        ("eye=0,-1,0,look-at=0,0,0,up=0,1,0", "parallel"),
        ("eye=0,-1,0,look-at=0,0,0,width=-3", "width"),
        ("eye=0,-1,0,look-at=0,0,0,size=3by4", "size"),
        ("eye=0,-1,0,look-at=0,0,0,zoom=2", "unknown key 'zoom'"),
        ("eye=0,-1,x,look-at=0,0,0", "not a number"),
        ("", "empty"),
    ] {
        let err = bad.parse::<Camera>().unwrap_err().to_string();
        assert!(err.contains(needle) && err.starts_with("invalid camera"), "{bad}: {err}");
    }
}

proptest! {
    #[test]
    fn any_valid_camera_round_trips(
        eye in prop::array::uniform3(-1e6f64..1e6), target in prop::array::uniform3(-1e6f64..1e6),
        fov in 0.01f64..179.9, w in 1u32..10000, h in 1u32..10000,
    ) {
        if let Ok(cam) = Camera::new(DVec3::from(eye), DVec3::from(target), DVec3::Z, fov, w, h) {
            prop_assert_eq!(cam.to_string().parse::<Camera>().unwrap(), cam);
        }
    }
}
