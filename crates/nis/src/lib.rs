//! nis
