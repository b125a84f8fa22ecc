//! E-cube (dimension-order) routing on the hypercube: a message for a
//! non-neighbour goes first along the lowest dimension in which the current
//! node's address differs from the target's, one bit per hop. Deadlock-free
//! on the hypercube and at most d hops.

/// A node of the hypercube: its address, 0..2^d.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeId(pub u16);

impl NodeId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// The dimension of the link the next hop from `at` toward `to` takes, or
/// None when `at == to`.
pub fn next_dimension(at: NodeId, to: NodeId) -> Option<u32> {
    let diff = at.0 ^ to.0;
    (diff != 0).then(|| diff.trailing_zeros())
}

/// The neighbour of `at` across dimension `dim`.
pub fn neighbour(at: NodeId, dim: u32) -> NodeId {
    NodeId(at.0 ^ (1 << dim))
}

/// The binary-reflected Gray code of `i`: consecutive values differ in one
/// bit, so consecutive screen regions land on hypercube neighbours.
pub fn gray(i: u16) -> u16 {
    i ^ (i >> 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, rng_algorithm: proptest::test_runner::RngAlgorithm::ChaCha, ..ProptestConfig::default() })]
        #[test]
        fn ecube_reaches_the_target_in_at_most_d_hops_one_bit_each(d in 0u32..=10, a in any::<u16>(), b in any::<u16>()) {
            let mask = ((1u32 << d) - 1) as u16;
            let (from, to) = (NodeId(a & mask), NodeId(b & mask));
            let mut at = from;
            let mut hops = 0;
            let mut last_dim = None;
            while let Some(dim) = next_dimension(at, to) {
                prop_assert!(dim < d.max(1));
                // Dimension order: strictly increasing dimensions.
                prop_assert!(last_dim.is_none_or(|l| dim > l));
                last_dim = Some(dim);
                let next = neighbour(at, dim);
                prop_assert_eq!((next.0 ^ at.0).count_ones(), 1);
                at = next;
                hops += 1;
            }
            prop_assert_eq!(at, to);
            prop_assert!(hops <= d);
            prop_assert_eq!(hops, (from.0 ^ to.0).count_ones());
        }
    }

    #[test]
    fn gray_codes_are_neighbours() {
        for i in 0..1023u16 {
            assert_eq!((gray(i) ^ gray(i + 1)).count_ones(), 1);
        }
    }
}
