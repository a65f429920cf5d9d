//! K-means clustering of emitter points into the K emitters of stage 2 (paper Sec. "Emitter
//! Semantic Field": the surface points that F_e marks are clustered by K-means, one learnable
//! emission L\[k\] per cluster).
//!
//! Seeding is k-means++ (Arthur & Vassilvitskii 2007: each next centre drawn with probability
//! proportional to D², the squared distance to the nearest centre so far), then Lloyd iterations;
//! the best of a few restarts (lowest within-cluster sum of squares) is kept.
//!
//! K is chosen automatically unless configured: the smallest K whose clusters are all spatially
//! compact, i.e. each cluster's points form one connected piece when points closer than a link
//! distance are joined. Two lamps at opposite ends of a room are one cluster at K = 1 but not a
//! connected one, so K grows until each lamp has its own; a single large ceiling panel is
//! connected at K = 1 and stays one emitter (a criterion on the cluster's size alone would split
//! it). Connected pieces holding fewer than a fraction of the points are dropped first, as stray
//! positives of the emitter field.

use i2sdf_data::KdTree;
use rand::Rng;

/// One cluster of a clustering.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    pub centre: [f64; 3],
    /// Axis-aligned extent of its points (max − min per axis).
    pub extent: [f64; 3],
    /// Largest distance of one of its points from the centre.
    pub radius: f64,
    /// Indices of its points in the input.
    pub members: Vec<usize>,
}

/// How emitter points are clustered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClusterSettings {
    /// Fixed K, or `None` for the smallest K whose clusters are connected.
    pub k: Option<usize>,
    /// Largest K tried by the automatic choice.
    pub max_k: usize,
    /// Points closer than this are neighbours (same units as the points).
    pub link: f64,
    /// Clusters with fewer than this fraction of the points are dropped.
    pub min_fraction: f64,
    pub restarts: usize,
    pub iterations: usize,
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// k-means++ seeding then Lloyd iterations; returns the centres and each point's label. `k` is
/// clamped to the number of points.
pub fn kmeans(points: &[[f64; 3]], k: usize, iterations: usize, rng: &mut impl Rng) -> (Vec<[f64; 3]>, Vec<usize>) {
    let n = points.len();
    let k = k.min(n);
    if k == 0 {
        return (Vec::new(), vec![0; n]);
    }
    // k-means++: D² weighting.
    let mut centres = vec![points[rng.gen_range(0..n)]];
    let mut d2: Vec<f64> = points.iter().map(|p| dist2(p, &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total > 0.0 {
            let mut u = rng.gen::<f64>() * total;
            let mut pick = n - 1;
            for (i, &w) in d2.iter().enumerate() {
                if u < w {
                    pick = i;
                    break;
                }
                u -= w;
            }
            pick
        } else {
            rng.gen_range(0..n)
        };
        let c = points[next];
        for (p, d) in points.iter().zip(d2.iter_mut()) {
            *d = d.min(dist2(p, &c));
        }
        centres.push(c);
    }
    let mut labels = vec![0usize; n];
    for _ in 0..iterations.max(1) {
        let mut changed = false;
        for (p, l) in points.iter().zip(labels.iter_mut()) {
            let best = (0..k)
                .min_by(|&a, &b| dist2(p, &centres[a]).total_cmp(&dist2(p, &centres[b])))
                .expect("k > 0");
            changed |= best != *l;
            *l = best;
        }
        let mut sum = vec![[0.0f64; 3]; k];
        let mut count = vec![0usize; k];
        for (p, &l) in points.iter().zip(&labels) {
            for a in 0..3 {
                sum[l][a] += p[a];
            }
            count[l] += 1;
        }
        for c in 0..k {
            if count[c] > 0 {
                centres[c] = sum[c].map(|s| s / count[c] as f64);
            }
        }
        if !changed {
            break;
        }
    }
    (centres, labels)
}

/// Within-cluster sum of squared distances.
pub fn inertia(points: &[[f64; 3]], centres: &[[f64; 3]], labels: &[usize]) -> f64 {
    points.iter().zip(labels).map(|(p, &l)| dist2(p, &centres[l])).sum()
}

/// Connected components of the points when points closer than `link` are joined (those with
/// `dist2 <= link²`, found by a [`KdTree`] of the points with that test, in f64): a label per
/// point, numbered in the order of each component's lowest point index, and the number of
/// components.
pub fn components(points: &[[f64; 3]], link: f64) -> (Vec<usize>, usize) {
    let tree = KdTree::new(points);
    let mut label = vec![usize::MAX; points.len()];
    let mut count = 0;
    let mut stack = Vec::new();
    for start in 0..points.len() {
        if label[start] != usize::MAX {
            continue;
        }
        label[start] = count;
        stack.push(start);
        while let Some(i) = stack.pop() {
            // The order of the neighbours does not matter: the components are sets.
            tree.for_each_within(points[i], link, |j| {
                if label[j] == usize::MAX {
                    label[j] = count;
                    stack.push(j);
                }
            });
        }
        count += 1;
    }
    (label, count)
}

/// Median distance from (up to 512 evenly chosen) points to their nearest other point.
pub fn median_spacing(points: &[[f64; 3]]) -> f64 {
    if points.len() < 2 {
        return 0.0;
    }
    let step = points.len().div_ceil(512);
    let mut d: Vec<f64> = (0..points.len())
        .step_by(step)
        .map(|i| {
            points
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| dist2(&points[i], q))
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// Are the points one connected piece at link distance `link`?
pub fn is_connected(points: &[[f64; 3]], link: f64) -> bool {
    points.len() <= 1 || components(points, link).1 == 1
}

fn best_of_restarts(
    points: &[[f64; 3]],
    k: usize,
    settings: &ClusterSettings,
    rng: &mut impl Rng,
) -> (Vec<[f64; 3]>, Vec<usize>) {
    let mut best: Option<(f64, Vec<[f64; 3]>, Vec<usize>)> = None;
    for _ in 0..settings.restarts.max(1) {
        let (c, l) = kmeans(points, k, settings.iterations, rng);
        let e = inertia(points, &c, &l);
        if best.as_ref().is_none_or(|b| e < b.0) {
            best = Some((e, c, l));
        }
    }
    let (_, c, l) = best.expect("one restart");
    (c, l)
}

fn clusters_of(points: &[[f64; 3]], centres: &[[f64; 3]], labels: &[usize]) -> Vec<Cluster> {
    (0..centres.len())
        .map(|c| {
            let members: Vec<usize> = (0..points.len()).filter(|&i| labels[i] == c).collect();
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            let mut radius = 0.0f64;
            for &i in &members {
                for a in 0..3 {
                    lo[a] = lo[a].min(points[i][a]);
                    hi[a] = hi[a].max(points[i][a]);
                }
                radius = radius.max(dist2(&points[i], &centres[c]).sqrt());
            }
            let extent = if members.is_empty() {
                [0.0; 3]
            } else {
                [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]]
            };
            Cluster {
                centre: centres[c],
                extent,
                radius,
                members,
            }
        })
        .collect()
}

/// Clusters emitter points into emitters (see the module comment). Returns the clusters kept,
/// largest first, and the K that was chosen before small clusters were dropped.
pub fn cluster_emitters(
    all_points: &[[f64; 3]],
    settings: &ClusterSettings,
    rng: &mut impl Rng,
) -> (Vec<Cluster>, usize) {
    // Stray positives first: connected pieces with fewer than min_fraction of the points go.
    let (piece, pieces) = components(all_points, settings.link);
    let mut size = vec![0usize; pieces];
    for &p in &piece {
        size[p] += 1;
    }
    let min = (settings.min_fraction * all_points.len() as f64).ceil() as usize;
    let kept: Vec<usize> = (0..all_points.len()).filter(|&i| size[piece[i]] >= min).collect();
    let points: Vec<[f64; 3]> = kept.iter().map(|&i| all_points[i]).collect();
    let points = &points[..];
    if points.is_empty() {
        return (Vec::new(), 0);
    }
    let (centres, labels, k) = match settings.k {
        Some(k) => {
            let (c, l) = best_of_restarts(points, k, settings, rng);
            (c, l, k)
        }
        None => {
            let mut chosen = None;
            for k in 1..=settings.max_k.max(1) {
                let (c, l) = best_of_restarts(points, k, settings, rng);
                let compact = (0..c.len()).all(|ci| {
                    let pts: Vec<[f64; 3]> = (0..points.len()).filter(|&i| l[i] == ci).map(|i| points[i]).collect();
                    // A cluster too small to keep does not need to be connected.
                    (pts.len() as f64) < settings.min_fraction * points.len() as f64
                        || is_connected(&pts, settings.link)
                });
                let last = k == settings.max_k.max(1);
                if compact || last {
                    chosen = Some((c, l, k));
                    break;
                }
            }
            chosen.expect("at least K = 1 is tried")
        }
    };
    let mut clusters: Vec<Cluster> = clusters_of(points, &centres, &labels)
        .into_iter()
        .filter(|c| !c.members.is_empty() && c.members.len() >= min)
        .map(|mut c| {
            c.members.iter_mut().for_each(|m| *m = kept[*m]);
            c
        })
        .collect();
    clusters.sort_by(|a, b| b.members.len().cmp(&a.members.len()));
    (clusters, k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64;

    fn blob(rng: &mut Pcg64, c: [f64; 3], half: [f64; 3], n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|_| std::array::from_fn(|a| c[a] + rng.gen_range(-half[a]..=half[a])))
            .collect()
    }

    fn settings() -> ClusterSettings {
        ClusterSettings {
            k: None,
            max_k: 8,
            link: 0.15,
            min_fraction: 0.01,
            restarts: 4,
            iterations: 50,
        }
    }

    /// A ceiling panel (1.25 × 0.8 m) and a bulb 2 m away, like the default room: K = 2 is found,
    /// the centres are the shapes' centres, and the panel is not split although it is large.
    #[test]
    fn finds_a_panel_and_a_bulb() {
        let mut rng = Pcg64::seed_from_u64(3);
        let mut pts = blob(&mut rng, [-0.6, 2.65, 0.0], [0.62, 0.0, 0.41], 3000);
        pts.extend(blob(&mut rng, [-1.8, 1.8, -1.5], [0.1, 0.1, 0.1], 400));
        // Stray positives far from both.
        pts.extend(blob(&mut rng, [1.5, 0.3, 1.5], [0.01; 3], 5));
        let (clusters, k) = cluster_emitters(&pts, &settings(), &mut rng);
        assert_eq!(k, 2, "the stray points are dropped before clustering");
        assert_eq!(clusters.len(), 2, "{clusters:?}");
        let near = |c: &Cluster, p: [f64; 3]| dist2(&c.centre, &p).sqrt() < 0.05;
        assert!(near(&clusters[0], [-0.6, 2.65, 0.0]) && clusters[0].members.len() == 3000);
        assert!(near(&clusters[1], [-1.8, 1.8, -1.5]) && clusters[1].members.len() == 400);
        assert!((clusters[0].extent[0] - 1.24).abs() < 0.02 && clusters[0].extent[1] == 0.0);
        assert!(clusters[1].radius < 0.18);
    }

    #[test]
    fn a_fixed_k_is_kept_and_d2_seeding_separates_blobs() {
        let mut rng = Pcg64::seed_from_u64(5);
        let mut pts = Vec::new();
        for c in [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.0, 5.0]] {
            pts.extend(blob(&mut rng, c, [0.2; 3], 200));
        }
        let s = ClusterSettings {
            k: Some(4),
            ..settings()
        };
        let (clusters, k) = cluster_emitters(&pts, &s, &mut rng);
        assert_eq!((k, clusters.len()), (4, 4));
        assert!(clusters.iter().all(|c| c.members.len() == 200 && c.radius < 0.4));
    }

    #[test]
    fn connectivity_follows_the_link_distance() {
        let line: Vec<[f64; 3]> = (0..50).map(|i| [i as f64 * 0.1, 0.0, 0.0]).collect();
        assert!(is_connected(&line, 0.11));
        let mut gap = line.clone();
        gap.push([10.0, 0.0, 0.0]);
        assert!(!is_connected(&gap, 0.11));
        assert!(is_connected(&[], 0.1) && is_connected(&[[1.0, 2.0, 3.0]], 0.1));
        // Points exactly `link` apart are joined (`<=`), a hair further apart are not.
        let exact: Vec<[f64; 3]> = (0..20).map(|i| [0.0, i as f64 * 0.25, 3.0]).collect();
        assert!(is_connected(&exact, 0.25));
        assert!(!is_connected(&exact, f64::from_bits(0.25f64.to_bits() - 1)));
    }

    /// Random clouds at several link distances (on a lattice of the link too, where many pairs
    /// are exactly `link` apart): the same labels as joining every pair with `dist2 <= link²`.
    #[test]
    fn components_match_brute_force() {
        let mut rng = Pcg64::seed_from_u64(12);
        let mut pts = blob(&mut rng, [0.0; 3], [1.0; 3], 600);
        pts.extend((0..125).map(|i| {
            [
                (i % 5) as f64 * 0.5 + 3.0,
                (i / 5 % 5) as f64 * 0.5,
                (i / 25) as f64 * 0.5,
            ]
        }));
        for link in [0.05, 0.1, 0.2, 0.5] {
            let mut label: Vec<usize> = (0..pts.len()).collect();
            fn root(label: &[usize], mut i: usize) -> usize {
                while label[i] != i {
                    i = label[i];
                }
                i
            }
            for i in 0..pts.len() {
                for j in 0..i {
                    if dist2(&pts[i], &pts[j]) <= link * link {
                        let (a, b) = (root(&label, i), root(&label, j));
                        label[a.max(b)] = a.min(b);
                    }
                }
            }
            // Renumber by lowest index, as `components` does.
            let (mut number, mut expected) = (std::collections::HashMap::new(), Vec::new());
            for i in 0..pts.len() {
                let r = root(&label, i);
                let next = number.len();
                expected.push(*number.entry(r).or_insert(next));
            }
            assert_eq!(components(&pts, link), (expected, number.len()), "link {link}");
        }
    }

    /// Forty points spread over the same panel (a small cache): still one emitter, not pieces.
    #[test]
    fn a_sparsely_sampled_panel_stays_one_emitter() {
        let mut rng = Pcg64::seed_from_u64(8);
        let mut pts = blob(&mut rng, [-0.6, 2.65, 0.0], [0.62, 0.0, 0.41], 40);
        pts.extend(blob(&mut rng, [-1.8, 1.8, -1.5], [0.1, 0.1, 0.1], 12));
        let s = ClusterSettings {
            link: 0.05,
            min_fraction: 0.05,
            ..settings()
        };
        let (clusters, _) = cluster_emitters(&pts, &s, &mut rng);
        assert_eq!(clusters.len(), 2, "{clusters:?}");
    }

    #[test]
    fn no_points_no_emitters() {
        let mut rng = Pcg64::seed_from_u64(0);
        assert_eq!(cluster_emitters(&[], &settings(), &mut rng).0.len(), 0);
    }
}
