//! Ks and ρ as a few glTF materials. A glTF vertex carries one colour (COLOR_0, which multiplies
//! the base colour: Kd here), not a specular colour or a roughness, so without textures the faces
//! are grouped by their (Ks, ρ) into at most K materials: weighted K-means (weights: face areas)
//! from a farthest-point start, deterministic.

/// Lloyd iterations after the start.
const ITERATIONS: usize = 25;

/// Clusters `features` (one row of `dim` values per item, weights ≥ 0) into at most `k` groups.
/// Returns each item's group and the groups' weighted means; groups that end up empty are
/// dropped (and the labels renumbered), so every returned centre has items.
pub fn kmeans(features: &[f32], dim: usize, weights: &[f32], k: usize) -> (Vec<u32>, Vec<Vec<f32>>) {
    let n = weights.len();
    assert_eq!(features.len(), n * dim);
    if n == 0 || k == 0 {
        return (vec![0; n], Vec::new());
    }
    let row = |i: usize| &features[i * dim..(i + 1) * dim];
    let dist2 = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>();
    // farthest-point start from the heaviest item
    let first = (0..n).max_by(|&a, &b| weights[a].total_cmp(&weights[b])).unwrap_or(0);
    let mut centres: Vec<Vec<f32>> = vec![row(first).to_vec()];
    let mut nearest: Vec<f32> = (0..n).map(|i| dist2(row(i), &centres[0])).collect();
    while centres.len() < k {
        let (far, &d) = nearest
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("n > 0");
        if d <= 0.0 {
            break; // fewer distinct rows than k
        }
        centres.push(row(far).to_vec());
        let c = centres.last().unwrap().clone();
        for (i, nd) in nearest.iter_mut().enumerate() {
            *nd = nd.min(dist2(row(i), &c));
        }
    }
    let mut labels = vec![0u32; n];
    for _ in 0..ITERATIONS {
        for (i, l) in labels.iter_mut().enumerate() {
            *l = (0..centres.len())
                .min_by(|&a, &b| dist2(row(i), &centres[a]).total_cmp(&dist2(row(i), &centres[b])))
                .unwrap() as u32;
        }
        let mut sum = vec![vec![0.0f64; dim]; centres.len()];
        let mut w = vec![0.0f64; centres.len()];
        for i in 0..n {
            let l = labels[i] as usize;
            w[l] += weights[i] as f64;
            for (s, &x) in sum[l].iter_mut().zip(row(i)) {
                *s += weights[i] as f64 * x as f64;
            }
        }
        for (c, (s, &w)) in centres.iter_mut().zip(sum.iter().zip(&w)) {
            if w > 0.0 {
                *c = s.iter().map(|v| (v / w) as f32).collect();
            }
        }
    }
    // drop the groups with no item, renumbering the labels
    let mut used = vec![false; centres.len()];
    for &l in &labels {
        used[l as usize] = true;
    }
    let mut renumber = vec![u32::MAX; centres.len()];
    let mut kept = Vec::new();
    for (c, centre) in centres.into_iter().enumerate() {
        if used[c] {
            renumber[c] = kept.len() as u32;
            kept.push(centre);
        }
    }
    (labels.into_iter().map(|l| renumber[l as usize]).collect(), kept)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separates_well_apart_groups_and_means_them_by_weight() {
        // three materials: matte (Ks 0, ρ 0.9), glossy (Ks 0.05, ρ 0.2), a mirror (Ks 0.9, ρ 0.05)
        let truth = [[0.0, 0.0, 0.0, 0.9], [0.05, 0.05, 0.05, 0.2], [0.9, 0.9, 0.9, 0.05]];
        let mut f = Vec::new();
        let mut w = Vec::new();
        for i in 0..300 {
            let t = truth[i % 3];
            let jitter = ((i * 37 % 11) as f32 - 5.0) * 1e-3;
            f.extend(t.iter().map(|v| v + jitter));
            w.push(1.0 + (i % 2) as f32);
        }
        let (labels, centres) = kmeans(&f, 4, &w, 3);
        assert_eq!(centres.len(), 3);
        for i in 0..300 {
            assert_eq!(labels[i], labels[i % 3], "item {i}");
        }
        for (t, &l) in truth.iter().zip(&labels[..3]) {
            for (a, b) in t.iter().zip(&centres[l as usize]) {
                assert!((a - b).abs() < 2e-3, "{t:?} vs {:?}", centres[l as usize]);
            }
        }
    }

    #[test]
    fn fewer_distinct_rows_than_k_gives_fewer_groups() {
        let f = vec![0.5, 0.5, 0.5, 0.5, 0.1, 0.2];
        let (labels, centres) = kmeans(&f, 2, &[1.0, 1.0, 1.0], 8);
        assert_eq!(centres.len(), 2);
        assert_eq!(labels[0], labels[1]);
        assert_ne!(labels[0], labels[2]);
        assert_eq!(kmeans(&[], 2, &[], 4), (vec![], vec![]));
    }
}
