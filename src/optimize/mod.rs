//! The optimizer: the paper's Algorithm 1. (Being written: issue 6.)
