//! What nimbus's benchmarks share with the tests: the unseen scenes ([`scenes`]).

pub mod scenes;
