//! The sweep on a rendered bar in front of a wall.

use super::*;
use crate::camera::look_at;

/// A textured wall at z = 3 and a thin bar of one colour at z = 2 in front of it (x ∈
/// [−0.02, 0.02], all y), seen by cameras along x at z = 0 looking down +z; `plain`: wall and
/// bar of one grey. Returns the distance, the colour and whether the bar was hit.
fn scene_hit(o: DVec3, d: DVec3, plain: bool) -> (f64, [f32; 3], bool) {
    let t_bar = (2.0 - o.z) / d.z;
    let xb = o.x + t_bar * d.x;
    if xb.abs() <= 0.02 {
        return (t_bar, if plain { [0.5; 3] } else { [0.9, 0.1, 0.1] }, true);
    }
    let t = (3.0 - o.z) / d.z;
    let p = o + t * d;
    if plain {
        return (t, [0.5; 3], false);
    }
    // A smooth but non-repeating texture (no two wall points alike along a ray's sweep).
    let v = |a: f64| (0.5 + 0.4 * (a).sin()) as f32;
    (
        t,
        [
            v(7.0 * p.x + 3.0 * p.y),
            v(5.0 * p.y - 11.0 * p.x),
            v(13.0 * p.x * p.y + 2.0 * p.x),
        ],
        false,
    )
}

/// A view's rendering: colour, sensor depth, where the bar is, and the low-confidence
/// footprints.
struct Rendered {
    rgb: ImageF32,
    depth: ImageF32,
    bar: Vec<bool>,
    low: ImageF32,
}

/// Renders a view: colour everywhere, and a sensor depth on every fourth pixel that drops the
/// samples whose 4×4 footprint touches the bar (a flying pixel, low confidence: their
/// footprints are `low`).
fn render(cam: &Camera, plain: bool) -> Rendered {
    let (w, h) = (cam.width, cam.height);
    let mut rgb = ImageF32::new(w, h, 3);
    let mut depth = ImageF32::new(w, h, 1);
    let mut low = ImageF32::new(w, h, 1);
    let mut bar = vec![false; w * h];
    let mut z_of = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (o, d, cos) = cam.ray(x as f64 + 0.5, y as f64 + 0.5);
            let (t, c, on_bar) = scene_hit(o, d, plain);
            rgb.pixel_mut(x, y).copy_from_slice(&c);
            z_of[y * w + x] = (t * cos) as f32;
            bar[y * w + x] = on_bar;
        }
    }
    for y in (2..h).step_by(4) {
        for x in (2..w).step_by(4) {
            let footprint = |f: &mut dyn FnMut(usize)| {
                for yy in y.saturating_sub(2)..(y + 2).min(h) {
                    for xx in x.saturating_sub(2)..(x + 2).min(w) {
                        f(yy * w + xx)
                    }
                }
            };
            let mut touches = false;
            footprint(&mut |p| touches |= bar[p]);
            if touches {
                footprint(&mut |p| low.data[p] = 1.0);
            } else {
                depth.data[y * w + x] = z_of[y * w + x];
            }
        }
    }
    Rendered { rgb, depth, bar, low }
}

/// Seven cameras along x looking at the wall, each with its rendering.
fn bar_scene(plain: bool) -> (Vec<Camera>, Vec<Rendered>) {
    let cams: Vec<Camera> = (0..7)
        .map(|k| {
            let eye = DVec3::new(-0.6 + 0.2 * k as f64, 0.05 * (k % 3) as f64, 0.0);
            let mut c = Camera::from_opengl_c2w(96, 72, 80.0, 80.0, 48.0, 36.0, glam::DMat4::IDENTITY);
            c.c2w = look_at(eye, DVec3::new(0.0, 0.0, 3.0), DVec3::new(0.0, -1.0, 0.0));
            c
        })
        .collect();
    let rendered = cams.iter().map(|c| render(c, plain)).collect();
    (cams, rendered)
}

/// The bar the sensor lost is found from the images, within a few centimetres, on most of
/// its pixels; no wall pixel gets a depth, not even those the edge support would place at
/// the bar (the wall explains their colour).
#[test]
fn a_thin_bar_the_sensor_lost_is_found_and_the_wall_is_left() {
    let (cams, rendered) = bar_scene(false);
    let views = photo_views(&cams, &rendered, true);
    let found = photo_depth(&views, &[3], &PhotoDepthParams::default());
    let pd = found[0].as_ref().expect("the view has depth");
    let bar = &rendered[3].bar;
    let cam = &cams[3];
    let (mut bar_pixels, mut bar_found, mut bar_right) = (0, 0, 0);
    for (p, &z) in pd.depth.data.iter().enumerate() {
        if bar[p] {
            bar_pixels += 1;
            if z > 0.0 {
                bar_found += 1;
                let (_, _, cos) = cam.ray((p % cam.width) as f64 + 0.5, (p / cam.width) as f64 + 0.5);
                bar_right += ((z as f64 / cos - 2.0 / cos).abs() < 0.05) as usize;
            }
        } else {
            assert_eq!(z, 0.0, "a wall pixel got depth {z} (pixel {p})");
        }
    }
    assert!(bar_pixels > 100, "{bar_pixels}");
    assert!(
        bar_found * 2 > bar_pixels,
        "found {bar_found} of the bar's {bar_pixels} pixels"
    );
    assert_eq!(bar_right, bar_found, "a bar pixel's depth off by over 5 cm");
    assert_eq!(pd.found, bar_found);
}

/// [`IN_FRONT`]: a depth found must lie in front of the *nearest* sensor sample around it.
/// The swept view's samples just left of the bar are set nearer than the bar (1.5 against
/// 2, as the edge of something the sensor saw would be), the wall's samples to its right
/// kept: the background and so the sweep are unchanged, and without the rule the bar is
/// found as before; with it every bar pixel is rejected as seen through.
#[test]
fn a_depth_behind_a_nearer_sample_beside_it_is_rejected() {
    let (cams, mut rendered) = bar_scene(false);
    let w = cams[3].width;
    let Rendered { depth, bar, .. } = &mut rendered[3];
    let mut injected = 0;
    for p in 0..depth.data.len() {
        let (x, y) = (p % w, p / w);
        // A bar pixel 1–6 columns to the right of this sample, in its row.
        let left_of_bar = (x + 1..(x + 7).min(w)).any(|xx| bar[y * w + xx]);
        if depth.data[p] > 0.0 && left_of_bar {
            depth.data[p] = 1.5;
            injected += 1;
        }
    }
    assert!(injected > 10, "{injected} samples set nearer");
    let views = photo_views(&cams, &rendered, false);
    let bar = &rendered[3].bar;
    let count = |in_front: bool| {
        let params = PhotoDepthParams {
            in_front,
            ..PhotoDepthParams::default()
        };
        let found = photo_depth(&views, &[3], &params);
        let pd = found[0].as_ref().expect("the view has depth");
        let on_bar = |o: Outcome| (0..bar.len()).filter(|&p| bar[p] && pd.outcome[p] == o as u8).count();
        (on_bar(Outcome::Found), on_bar(Outcome::SeenThrough))
    };
    let bar_pixels = bar.iter().filter(|b| **b).count();
    let (found_off, _) = count(false);
    let (found_on, seen_on) = count(true);
    assert!(
        found_off * 2 > bar_pixels,
        "without the rule {found_off} of {bar_pixels} bar pixels found"
    );
    assert_eq!(found_on, 0, "with the rule a bar pixel behind a nearer sample was kept");
    assert!(
        seen_on >= found_off,
        "with the rule {seen_on} bar pixels seen through, {found_off} found without"
    );
}

/// The views of a rendered scene; `low`: with their low-confidence footprints.
fn photo_views<'a>(cams: &'a [Camera], rendered: &'a [Rendered], low: bool) -> Vec<PhotoView<'a>> {
    cams.iter()
        .zip(rendered)
        .map(|(camera, r)| PhotoView {
            camera,
            rgb: &r.rgb,
            depth: &r.depth,
            low: low.then_some(&r.low),
        })
        .collect()
}

/// [`EDGE_MIN_SUPPORT`]: a bar of the wall's own grey, which no colour can tell from the wall,
/// is placed where the other views' low-confidence footprints meet: most of its pixels
/// within 10 cm (a grid cell's footprint at the bar: 4 px at 2 m and 80 px focal length; with
/// one grey the colours cannot refine it), and every depth given lies between the bar and the
/// wall, within a footprint of the bar (the wall pixels that share the bar's footprints are
/// placed near it: with one grey nothing tells them apart; on a textured wall the colour
/// ratio does, as the test above checks with the footprints). Without the footprints, or with
/// the edge support off, nothing is found.
#[test]
fn a_bar_of_the_walls_colour_is_placed_by_the_low_confidence_footprints() {
    let (cams, rendered) = bar_scene(true);
    let cam = &cams[3];
    let bar = &rendered[3].bar;
    let bar_pixels = bar.iter().filter(|b| **b).count();
    let run = |low: bool, params: &PhotoDepthParams| {
        let views = photo_views(&cams, &rendered, low);
        photo_depth(&views, &[3], params).remove(0).expect("the view has depth")
    };
    let pd = run(true, &PhotoDepthParams::default());
    let (mut bar_right, mut off_bar) = (0, 0);
    for (p, &z) in pd.depth.data.iter().enumerate() {
        if z <= 0.0 {
            continue;
        }
        assert_eq!(pd.outcome[p], Outcome::FoundAtEdge as u8);
        let x = cam.backproject(p % cam.width, p / cam.width, z as f64);
        let d_bar = ((x.x.abs() - 0.02).max(0.0)).hypot(x.z - 2.0);
        // Beside the bar by at most a footprint, between it and the wall.
        off_bar += ((x.x.abs() - 0.02) > 0.1 || x.z < 1.9 || x.z > 3.0 * (1.0 - MIN_GAP)) as usize;
        bar_right += (bar[p] && d_bar < 0.1) as usize;
    }
    assert!(bar_pixels > 100, "{bar_pixels}");
    assert!(
        bar_right * 2 > bar_pixels,
        "{bar_right} of the bar's {bar_pixels} pixels placed within 10 cm"
    );
    assert_eq!(off_bar, 0, "{off_bar} depths away from the bar");
    assert_eq!(run(false, &PhotoDepthParams::default()).found, 0);
    let off = PhotoDepthParams {
        edge_min_support: 0,
        ..PhotoDepthParams::default()
    };
    assert_eq!(run(true, &off).found, 0);
}

#[test]
fn edge_depths_ringing_what_the_colours_found_are_cleared_and_a_lone_line_is_kept() {
    // A 4×4 block the colours found at 2 m, ringed by edge depths at 2.05 m; a line of edge
    // depths at 2 m eight pixels away; one edge depth beside the block but 30 % nearer.
    let (w, h) = (24, 12);
    let mut depth = ImageF32::new(w, h, 1);
    let mut outcome = vec![Outcome::Sensed as u8; w * h];
    fn put(depth: &mut ImageF32, outcome: &mut [u8], x: usize, y: usize, z: f32, o: Outcome) {
        depth.data[y * depth.width + x] = z;
        outcome[y * depth.width + x] = o as u8;
    }
    macro_rules! set {
        ($($a:expr),*) => { put(&mut depth, &mut outcome, $($a),*) };
    }
    for y in 3..9 {
        for x in 3..9 {
            let inside = (4..8).contains(&x) && (4..8).contains(&y);
            let (z, o) = if inside {
                (2.0, Outcome::Found)
            } else {
                (2.05, Outcome::FoundAtEdge)
            };
            set!(x, y, z, o);
        }
    }
    for y in 1..11 {
        set!(17, y, 2.0, Outcome::FoundAtEdge);
    }
    set!(9, 6, 1.4, Outcome::FoundAtEdge);
    let p = PhotoDepthParams::default();
    assert!(p.edge_clear_radius > 0, "the clearing is on by default");
    let dropped = clear_edges_near_colour(&mut depth, &mut outcome, &p);
    let at = |x: usize, y: usize| (depth.data[y * w + x], outcome[y * w + x]);
    // The ring's 20 pixels each have at least three of the block's within two pixels.
    assert_eq!(dropped, 20);
    for (x, y) in [(3, 3), (8, 3), (3, 8), (8, 8), (5, 3), (8, 6)] {
        assert_eq!(at(x, y), (0.0, Outcome::Cleared as u8), "ring pixel ({x}, {y})");
    }
    for y in 1..11 {
        assert_eq!(at(17, y), (2.0, Outcome::FoundAtEdge as u8), "line pixel {y}");
    }
    assert_eq!(
        at(9, 6),
        (1.4, Outcome::FoundAtEdge as u8),
        "the nearer edge depth is another object"
    );
    assert_eq!(at(5, 5), (2.0, Outcome::Found as u8));
    // Off: nothing dropped.
    let off = PhotoDepthParams {
        edge_clear_radius: 0,
        ..p
    };
    set!(3, 3, 2.05, Outcome::FoundAtEdge);
    assert_eq!(clear_edges_near_colour(&mut depth, &mut outcome, &off), 0);
}
