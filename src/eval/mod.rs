//! Evaluation against ground truth (DENSER Sec. VI).
