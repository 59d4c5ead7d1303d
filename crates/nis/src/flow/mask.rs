//! Which dimensions a coupling layer leaves alone (A, fed to the conditioner) and which it
//! transforms (B).
//!
//! D = 1: a single unconditional transform (A = ∅). D = 2: the two dimensions alternate. D > 2:
//! the ⌈log₂ D⌉ binary masks — dimension i is in A for mask b when bit b of i is 0 — each followed
//! by its complement, so every pair of dimensions is separated by at least one mask and every
//! dimension is transformed once per pair (Müller et al. 2018, Sec. 4.1).

/// The (A, B) partition of each of `layers` coupling layers in a `dim`-dimensional flow.
pub fn partitions(dim: usize, layers: usize) -> Vec<(Vec<usize>, Vec<usize>)> {
    if dim == 1 {
        return vec![(vec![], vec![0]); layers];
    }
    let bits = usize::BITS - (dim - 1).leading_zeros();
    let mut patterns = Vec::new();
    for b in 0..bits as usize {
        let (a, bb): (Vec<usize>, Vec<usize>) = (0..dim).partition(|i| (i >> b) & 1 == 0);
        patterns.push((a.clone(), bb.clone()));
        patterns.push((bb, a));
    }
    (0..layers)
        .map(|l| patterns[l % patterns.len()].clone())
        .collect()
}

/// The default number of coupling layers: one pass of all masks and complements.
pub fn default_layers(dim: usize) -> usize {
    if dim == 1 {
        1
    } else {
        2 * (usize::BITS - (dim - 1).leading_zeros()) as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_dimensions_alternate() {
        let p = partitions(2, 3);
        assert_eq!(p[0], (vec![0], vec![1]));
        assert_eq!(p[1], (vec![1], vec![0]));
        assert_eq!(p[2], (vec![0], vec![1]));
        assert_eq!(default_layers(2), 2);
    }

    #[test]
    fn every_pair_is_separated_and_every_dimension_transformed() {
        for dim in 3..=17 {
            let p = partitions(dim, default_layers(dim));
            for (a, b) in &p {
                assert_eq!(a.len() + b.len(), dim);
                assert!(!a.is_empty() && !b.is_empty());
            }
            for i in 0..dim {
                assert!(p.iter().any(|(_, b)| b.contains(&i)));
                for j in i + 1..dim {
                    assert!(p.iter().any(|(a, b)| a.contains(&i) && b.contains(&j)));
                }
            }
        }
        assert_eq!(partitions(1, 1), vec![(vec![], vec![0])]);
    }
}
