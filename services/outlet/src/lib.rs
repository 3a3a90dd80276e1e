//! What the `outlet` command shares with other programs and tests: the built-in
//! templates, trained from rendered views.

pub mod templates;
