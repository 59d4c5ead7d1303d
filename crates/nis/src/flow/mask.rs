//! Which dimensions a coupling layer leaves alone (A, fed to the conditioner) and which it
//! transforms (B).
//!
//! D = 1: a single unconditional transform (A = ∅). D = 2: the two dimensions alternate. D > 2,
//! two layouts ([`Masks`]):
//! - **binary** (the paper's, the default): the ⌈log₂ D⌉ binary masks — dimension i is in A for
//!   mask b when bit b of i is 0 — each followed by its complement, so every pair of dimensions
//!   is separated by at least one mask and every dimension is transformed once per pair, ⌈log₂ D⌉
//!   times in 2⌈log₂ D⌉ layers (Müller et al. 2018, Sec. 4.1).
//! - **codes**: every dimension gets a distinct L-bit code with w = ⌊L/2⌋ ones, and layer b
//!   transforms the dimensions whose bit b is set. Distinct codes of equal weight are never
//!   subsets of one another, so for every ordered pair (i, j) some layer has i in A and j in B,
//!   as with the binary masks (which are such a code of length 2⌈log₂ D⌉ and weight ⌈log₂ D⌉).
//!   L is the smallest with C(L, w) ≥ D (5 at D = 8, 6 at D = 16, 8 at D = 64), and the codes are
//!   chosen greedily so that every layer transforms about as many dimensions. Fewer layers and
//!   w transforms per dimension instead of ⌈log₂ D⌉: a cheaper flow with a higher variance per
//!   evaluation (docs/results/integration.md, "Flow masks: binary against codes").

use serde::{Deserialize, Serialize};

/// How the coupling layers split the dimensions (see the module's documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Masks {
    /// The paper's binary masks and their complements, 2⌈log₂ D⌉ layers.
    #[default]
    Binary,
    /// Constant-weight codes: the fewest layers that still separate every ordered pair.
    Codes,
}

impl Masks {
    /// Whether this is the default layout (which model files leave unwritten).
    pub fn is_binary(&self) -> bool {
        *self == Masks::Binary
    }
}

impl std::str::FromStr for Masks {
    type Err = crate::error::Error;

    /// `"binary"` or `"codes"`, the names of the JSON config.
    fn from_str(s: &str) -> crate::error::Result<Masks> {
        match s {
            "binary" => Ok(Masks::Binary),
            "codes" => Ok(Masks::Codes),
            _ => Err(crate::error::Error::Config(format!(
                "unknown masks {s:?} (expected \"binary\" or \"codes\")"
            ))),
        }
    }
}

/// The (A, B) partition of each of `layers` coupling layers in a `dim`-dimensional flow; the
/// layout's layers repeat in order when `layers` is larger than its own count. For a dimension
/// a valid [`crate::flow::FlowConfig`] allows (the codes enumerate 2^L candidates).
pub(crate) fn partitions(dim: usize, layers: usize, masks: Masks) -> Vec<(Vec<usize>, Vec<usize>)> {
    if dim == 1 {
        return vec![(vec![], vec![0]); layers];
    }
    let patterns = match masks {
        Masks::Codes if dim > 2 => code_partitions(dim),
        _ => binary_partitions(dim),
    };
    (0..layers)
        .map(|l| patterns[l % patterns.len()].clone())
        .collect()
}

fn binary_partitions(dim: usize) -> Vec<(Vec<usize>, Vec<usize>)> {
    let mut patterns = Vec::new();
    for b in 0..binary_bits(dim) {
        let (a, bb): (Vec<usize>, Vec<usize>) = (0..dim).partition(|i| (i >> b) & 1 == 0);
        patterns.push((a.clone(), bb.clone()));
        patterns.push((bb, a));
    }
    patterns
}

fn code_partitions(dim: usize) -> Vec<(Vec<usize>, Vec<usize>)> {
    let codes = codes(dim);
    (0..code_length(dim))
        .map(|b| (0..dim).partition(|&i| codes[i] >> b & 1 == 0))
        .collect()
}

/// ⌈log₂ D⌉ for D ≥ 2.
fn binary_bits(dim: usize) -> usize {
    (usize::BITS - (dim - 1).leading_zeros()) as usize
}

/// C(n, k), saturating.
fn binomial(n: usize, k: usize) -> usize {
    (0..k).fold(1usize, |c, i| c.saturating_mul(n - i) / (i + 1))
}

/// The codes' length L: the smallest with C(L, ⌊L/2⌋) ≥ D (D ≥ 3).
fn code_length(dim: usize) -> usize {
    (2..).find(|&l| binomial(l, l / 2) >= dim).unwrap_or(2)
}

/// One distinct L-bit code of weight ⌊L/2⌋ per dimension. Each dimension in turn takes the
/// unused code whose bits' layers transform the fewest dimensions so far (the first such code in
/// increasing order), which keeps the layers' sizes within one or two of each other.
fn codes(dim: usize) -> Vec<u32> {
    let l = code_length(dim);
    let weight = (l / 2) as u32;
    let mut candidates: Vec<u32> = (0u32..1 << l)
        .filter(|c| c.count_ones() == weight)
        .collect();
    let mut load = vec![0usize; l];
    let mut chosen = Vec::with_capacity(dim);
    for _ in 0..dim {
        let cost = |mut c: u32| {
            let mut sum = 0;
            while c != 0 {
                sum += load[c.trailing_zeros() as usize];
                c &= c - 1;
            }
            sum
        };
        let (at, _) = candidates
            .iter()
            .enumerate()
            .min_by_key(|&(i, &c)| (cost(c), i))
            .expect("C(L, L/2) >= D codes");
        let code = candidates.remove(at);
        for (b, n) in load.iter_mut().enumerate() {
            *n += (code >> b & 1) as usize;
        }
        chosen.push(code);
    }
    chosen
}

/// The default number of coupling layers: one pass of the layout's layers.
pub fn default_layers(dim: usize, masks: Masks) -> usize {
    match (dim, masks) {
        (1, _) => 1,
        (3.., Masks::Codes) => code_length(dim),
        _ => 2 * binary_bits(dim),
    }
}

/// The sizes (|A|, |B|) of the layout's own layers, without building them where that is cheap:
/// the binary masks in O(log D), the codes by choosing them (D ≤ `max_dim`, else `None`).
pub(crate) fn pattern_sizes(
    dim: usize,
    masks: Masks,
    max_dim: usize,
) -> Option<Vec<(usize, usize)>> {
    if dim <= 1 {
        return Some(vec![(0, dim)]);
    }
    if masks == Masks::Codes && dim > 2 {
        if dim > max_dim {
            return None;
        }
        return Some(
            code_partitions(dim)
                .iter()
                .map(|(a, b)| (a.len(), b.len()))
                .collect(),
        );
    }
    // Pattern 2b puts the dimensions with bit b clear in A, pattern 2b + 1 is its complement.
    let mut sizes = Vec::new();
    for b in 0..binary_bits(dim) {
        // In u128: 2^(b+1) reaches 2^64 for the largest dimensions.
        let (d, period) = (dim as u128, 1u128 << (b + 1));
        let clear = ((d / period) * (period / 2) + (d % period).min(period / 2)) as usize;
        sizes.push((clear, dim - clear));
        sizes.push((dim - clear, clear));
    }
    Some(sizes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_dimensions_alternate() {
        for masks in [Masks::Binary, Masks::Codes] {
            let p = partitions(2, 3, masks);
            assert_eq!(p[0], (vec![0], vec![1]));
            assert_eq!(p[1], (vec![1], vec![0]));
            assert_eq!(p[2], (vec![0], vec![1]));
            assert_eq!(default_layers(2, masks), 2);
        }
    }

    /// Every layer splits the dimensions into nonempty A and B, and for every ordered pair
    /// (i, j) some layer conditions j on i.
    fn check_separates(p: &[(Vec<usize>, Vec<usize>)], dim: usize) {
        for (a, b) in p {
            assert_eq!(a.len() + b.len(), dim);
            assert!(!a.is_empty() && !b.is_empty(), "{dim}: {p:?}");
        }
        for i in 0..dim {
            for j in 0..dim {
                if i != j {
                    assert!(
                        p.iter().any(|(a, b)| a.contains(&i) && b.contains(&j)),
                        "{dim}: {i} → {j} in no layer"
                    );
                }
            }
        }
    }

    #[test]
    fn every_pair_is_separated_and_every_dimension_transformed() {
        for dim in 3..=17 {
            let p = partitions(dim, default_layers(dim, Masks::Binary), Masks::Binary);
            check_separates(&p, dim);
            for i in 0..dim {
                let times = p.iter().filter(|(_, b)| b.contains(&i)).count();
                assert_eq!(times, binary_bits(dim));
            }
        }
        assert_eq!(partitions(1, 1, Masks::Binary), vec![(vec![], vec![0])]);
        assert_eq!(partitions(1, 1, Masks::Codes), vec![(vec![], vec![0])]);
    }

    #[test]
    fn codes_separate_every_ordered_pair_with_the_fewest_balanced_layers() {
        for dim in (3..=300).chain([1000]) {
            let layers = default_layers(dim, Masks::Codes);
            // The fewest: one layer less gives fewer codes of any single weight than dimensions
            // (C(L, ⌊L/2⌋) is the largest binomial of L).
            assert!(binomial(layers, layers / 2) >= dim);
            assert!(binomial(layers - 1, (layers - 1) / 2) < dim, "{dim}");
            let p = partitions(dim, layers, Masks::Codes);
            check_separates(&p, dim);
            for i in 0..dim {
                let times = p.iter().filter(|(_, b)| b.contains(&i)).count();
                assert_eq!(times, layers / 2, "{dim}");
            }
            let sizes: Vec<usize> = p.iter().map(|(_, b)| b.len()).collect();
            let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
            assert!(hi - lo <= 2, "{dim}: {sizes:?}");
            let expected = pattern_sizes(dim, Masks::Codes, usize::MAX).unwrap();
            let got: Vec<_> = p.iter().map(|(a, b)| (a.len(), b.len())).collect();
            assert_eq!(got, expected);
        }
        assert_eq!(default_layers(8, Masks::Codes), 5);
        assert_eq!(default_layers(16, Masks::Codes), 6);
        assert_eq!(default_layers(8, Masks::Binary), 6);
    }

    #[test]
    fn binary_sizes_match_the_partitions() {
        for dim in 1..=40 {
            let p = partitions(dim, default_layers(dim, Masks::Binary), Masks::Binary);
            let got: Vec<_> = p.iter().map(|(a, b)| (a.len(), b.len())).collect();
            assert_eq!(Some(got), pattern_sizes(dim, Masks::Binary, 0));
        }
    }

    #[test]
    fn codes_are_a_stable_layout() {
        // A model file stores the layout's name, not its masks: the masks must never change.
        let p = partitions(8, 5, Masks::Codes);
        let b: Vec<Vec<usize>> = p.into_iter().map(|(_, b)| b).collect();
        assert_eq!(b, EXPECTED_D8);
    }

    // By hand: the weight-2 codes of 5 bits in increasing order, each dimension taking the first
    // of least load: {0,1} {2,3} {0,4} {1,2} {3,4} {0,2} {1,3} {1,4}; layer b transforms the
    // dimensions whose code holds b.
    const EXPECTED_D8: [&[usize]; 5] = [
        &[0, 2, 5],
        &[0, 3, 6, 7],
        &[1, 3, 5],
        &[1, 4, 6],
        &[2, 4, 7],
    ];
}
