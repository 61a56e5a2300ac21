//! The review's plotting kit: why it exists is that every plot (`plots.rs`,
//! `error.rs`) draws on the same PNG areas with the same chart frame, axis
//! ranges and error text.

use plotters::coord::ranged1d::AsRangedCoord;
use plotters::coord::Shift;
use plotters::prelude::*;

/// A plotting error as text.
pub(super) fn err(x: impl std::fmt::Display) -> String {
    x.to_string()
}

/// A drawing area of a PNG file.
pub(super) type Area<'b> = DrawingArea<BitMapBackend<'b>, Shift>;

/// A chart drawn on an [`Area`], over `X` × `Y`.
pub(super) type Chart<'a, 'b, X, Y> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<X, Y>>;

/// The finite values' span, padded by 5% (at least 1 mm); `(0, 1)` when
/// there are none.
pub(super) fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

/// A captioned chart on `area` over `x` × `y`, with the margins and label
/// areas every plot here uses.
pub(super) fn chart<'a, 'b, X: AsRangedCoord, Y: AsRangedCoord>(
    area: &'a Area<'b>,
    caption: &str,
    x: X,
    y: Y,
) -> Result<Chart<'a, 'b, X::CoordDescType, Y::CoordDescType>, String> {
    ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
        .map_err(err)
}
