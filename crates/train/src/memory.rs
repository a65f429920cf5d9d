//! Training memory estimates (filled in below).
