//! What nimbus's benchmarks share with the tests: the unseen scenes, hand-made ([`scenes`])
//! and drawn at random from a seed ([`random`], issue #47).

pub mod random;
pub mod scenes;
