//! Unit tests of the volume readers.
