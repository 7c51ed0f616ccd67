//! Progressive triangle strips (after a Korean paper on "progressive strips", undated): a mesh as a strip of its base mesh plus
//! vertex splits that restore the original strip in place, so that every intermediate
//! level can be drawn as a strip without stripifying again.
//!
//! - [`stripify`] / [`unstripify`]: generalised strips of a triangle set and back.
//! - [`progressive`]: the quadric engine's collapses replayed on the strip; the splits in
//!   Naive-PS and E-PS form ([`Encoding`]); a [`Decoder`] that moves between levels.
//! - [`filter`]: DTFS and STSS, which drop what collapsed strips no longer draw.
//! - [`format`]: the `.tps` stream.

pub mod asset;
pub mod figure;
pub mod filter;
pub mod format;
mod lists;
pub mod measure;
pub mod order;
pub mod progressive;
pub mod stripify;

pub use filter::{dtfs, dtfs_into, stss};
pub use progressive::{
    progressive, Decoder, Encoding, Progressive, ProgressiveParams, Split, StripOrder,
};
pub use stripify::{stripify, unstripify, Join, StripParams, RESTART};

#[cfg(test)]
mod stripify_twin;
#[cfg(test)]
mod tests;
