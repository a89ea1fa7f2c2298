//! nimbus: the four tools live in `tools/`; this library is empty on purpose.
