//! Camera geometry (pixel (0,0) top-left, field of view, orthographic extent) and refusal of
//! degenerate specifications.

use gather::{Camera, GatherError};
use gather::{CameraSpec, Projection};
use glam::DVec3;

fn spec(
    eye: DVec3,
    target: DVec3,
    up: DVec3,
    projection: Projection,
    w: u32,
    h: u32,
) -> CameraSpec {
    CameraSpec {
        name: "test".into(),
        eye,
        target,
        up,
        projection,
        width: w,
        height: h,
    }
}

fn persp(fov: f64) -> Projection {
    Projection::Perspective { fov_y_degrees: fov }
}

#[test]
fn perspective_frame_and_field_of_view() {
    let eye = DVec3::new(1.0, -10.0, 2.0);
    let target = DVec3::new(1.0, 0.0, 2.0);
    let cam = Camera::from_spec(&spec(eye, target, DVec3::Z, persp(40.0), 200, 100)).unwrap();
    // The centre of the image looks at the target.
    let centre = cam.ray(100.0, 50.0);
    assert_eq!(centre.origin, eye);
    assert!((centre.direction - DVec3::Y).length() < 1e-12);
    // Top edge middle: 20° above the view direction (vertical fov 40°).
    let top = cam.ray(100.0, 0.0);
    assert!((top.direction.angle_between(DVec3::Y) - 20f64.to_radians()).abs() < 1e-12);
    assert!(top.direction.z > 0.0, "y = 0 is the top of the image");
    // Left edge middle: atan(aspect · tan 20°) to the left (−x when looking along +y, up +z).
    let left = cam.ray(0.0, 50.0);
    let want = (2.0 * 20f64.to_radians().tan()).atan();
    assert!((left.direction.angle_between(DVec3::Y) - want).abs() < 1e-12);
    assert!(left.direction.x < 0.0, "x = 0 is the left of the image");
    for (px, py) in [(0.0, 0.0), (13.5, 77.25), (200.0, 100.0)] {
        assert!((cam.ray(px, py).direction.length() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn orthographic_rays_are_parallel_and_span_the_height() {
    let eye = DVec3::new(0.0, 0.0, 10.0);
    let cam = Camera::orthographic(eye, DVec3::ZERO, DVec3::Y, 4.0, 8, 4).unwrap();
    let tl = cam.ray(0.0, 0.0);
    let br = cam.ray(8.0, 4.0);
    assert_eq!(tl.direction, -DVec3::Z);
    assert_eq!(br.direction, -DVec3::Z);
    // Height 4 world units, aspect 2: corners at (∓4, ±2) around the eye.
    assert!((tl.origin - DVec3::new(-4.0, 2.0, 10.0)).length() < 1e-12);
    assert!((br.origin - DVec3::new(4.0, -2.0, 10.0)).length() < 1e-12);
}

#[test]
fn up_need_not_be_orthogonal_to_the_view() {
    let cam = Camera::perspective(
        DVec3::ZERO,
        DVec3::new(0.0, 0.0, -5.0),
        DVec3::new(0.0, 1.0, 0.7),
        60.0,
        4,
        4,
    )
    .unwrap();
    assert!((cam.up - DVec3::Y).length() < 1e-12);
    assert!(cam.up.dot(cam.forward).abs() < 1e-12);
    assert!((cam.right - DVec3::X).length() < 1e-12);
}

#[test]
fn degenerate_cameras_are_refused() {
    let (e, t, up) = (DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::Y);
    let bad = [
        ("eye on target", spec(t, t, up, persp(40.0), 4, 4)),
        ("up parallel", spec(e, t, DVec3::Z, persp(40.0), 4, 4)),
        (
            "up antiparallel",
            spec(e, t, -DVec3::Z * 3.0, persp(40.0), 4, 4),
        ),
        ("zero up", spec(e, t, DVec3::ZERO, persp(40.0), 4, 4)),
        ("fov 0", spec(e, t, up, persp(0.0), 4, 4)),
        ("fov 180", spec(e, t, up, persp(180.0), 4, 4)),
        ("fov negative", spec(e, t, up, persp(-30.0), 4, 4)),
        ("fov NaN", spec(e, t, up, persp(f64::NAN), 4, 4)),
        ("width 0", spec(e, t, up, persp(40.0), 0, 4)),
        ("height 0", spec(e, t, up, persp(40.0), 4, 0)),
        ("eye NaN", spec(DVec3::NAN, t, up, persp(40.0), 4, 4)),
        (
            "ortho height 0",
            spec(e, t, up, Projection::Orthographic { height: 0.0 }, 4, 4),
        ),
        (
            "ortho height < 0",
            spec(e, t, up, Projection::Orthographic { height: -2.0 }, 4, 4),
        ),
        (
            "ortho height inf",
            spec(
                e,
                t,
                up,
                Projection::Orthographic {
                    height: f64::INFINITY,
                },
                4,
                4,
            ),
        ),
    ];
    for (what, s) in bad {
        match Camera::from_spec(&s) {
            Err(GatherError::Camera { name, message }) => {
                assert_eq!(name, "test");
                assert!(!message.is_empty());
            }
            other => panic!("{what}: expected a camera error, got {other:?}"),
        }
    }
    // The same with sensible values is accepted.
    assert!(Camera::from_spec(&spec(e, t, up, persp(40.0), 4, 4)).is_ok());
    assert!(Camera::from_spec(&spec(e, t, up, persp(179.0), 4, 4)).is_ok());
}

/// Whether the ray meets the box `[lo, hi]` at some `t ≥ 0` (slab test).
fn meets_box(ray: &medium::traversal::Ray, lo: DVec3, hi: DVec3) -> bool {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.direction[a]);
        if d == 0.0 {
            if o < lo[a] || o > hi[a] {
                return false;
            }
        } else {
            let (ta, tb) = ((lo[a] - o) / d, (hi[a] - o) / d);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    t0 <= t1
}

#[test]
fn no_ray_outside_the_pixel_bounds_meets_the_box() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut cropped = 0;
    for trial in 0..60 {
        let lo = DVec3::new(
            rng.random_range(0.0..10.0),
            rng.random_range(0.0..10.0),
            0.0,
        );
        let hi = lo + DVec3::new(rng.random_range(0.5..8.0), rng.random_range(0.5..8.0), 6.0);
        let centre = 0.5 * (lo + hi);
        // Eyes near and far; some inside the box, where nothing may be cropped.
        let distance = rng.random_range(0.0..40.0);
        let eye = centre
            + DVec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                0.3,
            ) * distance;
        let target = centre
            + DVec3::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                0.0,
            );
        let projection = if trial % 3 == 0 {
            Projection::Orthographic {
                height: rng.random_range(5.0..30.0),
            }
        } else {
            persp(rng.random_range(20.0..90.0))
        };
        let Ok(cam) = Camera::from_spec(&spec(eye, target, DVec3::Z, projection, 64, 48)) else {
            continue;
        };
        let [x0, y0, x1, y1] = cam.pixel_bounds(lo, hi);
        assert!(x0 <= x1 && x1 <= 64 && y0 <= y1 && y1 <= 48);
        if [x0, y0, x1, y1] != [0, 0, 64, 48] {
            cropped += 1;
        }
        // Sample each pixel outside the bounds at its corners, edge midpoints and centre.
        for y in 0..48u32 {
            for x in 0..64u32 {
                if (x0..x1).contains(&x) && (y0..y1).contains(&y) {
                    continue;
                }
                for (fx, fy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)] {
                    let ray = cam.ray(x as f64 + fx, y as f64 + fy);
                    assert!(
                        !meets_box(&ray, lo, hi),
                        "trial {trial}: pixel ({x}, {y}) outside {:?} sees the box",
                        [x0, y0, x1, y1]
                    );
                }
            }
        }
    }
    // The bounds must also do their job: most views of a box from outside crop something.
    assert!(cropped > 20, "only {cropped} of 60 views were cropped");
}
