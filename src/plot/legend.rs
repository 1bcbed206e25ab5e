//! Text boxes beside and on the panels: the legend column and the note of a histogram.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::chart::{msg, Area, BAND_ALPHA};
use super::style::{shorten, FONT};

/// Indices of the lines given a legend entry: all of them up to `max_entries`, otherwise every
/// k-th one and the last one.
pub(super) fn legend_indices(n: usize, max_entries: usize) -> Vec<usize> {
    let max_entries = max_entries.max(2);
    if n <= max_entries {
        return (0..n).collect();
    }
    let k = n.div_ceil(max_entries - 1);
    let mut idx: Vec<usize> = (0..n).step_by(k).collect();
    if idx.last() != Some(&(n - 1)) {
        idx.push(n - 1);
    }
    idx
}

/// One legend entry: a short sample (line, dashed line or translucent band) and a label.
pub(super) struct LegendEntry {
    pub(super) label: String,
    pub(super) color: RGBColor,
    pub(super) mark: LegendMark,
}

/// The sample drawn before a legend label.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum LegendMark {
    Line,
    Dashed,
    Band,
}

/// Height in pixels of one legend row.
pub(super) const LEGEND_ROW: i32 = 24;

/// Draws the legend entries in a column of `area`, starting `top` pixels from its top.
pub(super) fn draw_legend(
    area: &Area,
    top: i32,
    title: &str,
    entries: &[LegendEntry],
) -> Result<(), String> {
    let text = TextStyle::from((FONT, 17).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let x0 = 8;
    let mut y = top;
    if !title.is_empty() {
        area.draw_text(title, &text, (x0, y)).map_err(msg)?;
        y += LEGEND_ROW;
    }
    for entry in entries {
        let style = entry.color.stroke_width(2);
        match entry.mark {
            LegendMark::Dashed => {
                for k in 0..3 {
                    let a = x0 + 12 * k;
                    area.draw(&PathElement::new(vec![(a, y), (a + 7, y)], style))
                        .map_err(msg)?;
                }
            }
            LegendMark::Line => {
                area.draw(&PathElement::new(vec![(x0, y), (x0 + 31, y)], style))
                    .map_err(msg)?;
            }
            LegendMark::Band => {
                let corners = [(x0, y - 7), (x0 + 31, y + 7)];
                area.draw(&Rectangle::new(
                    corners,
                    entry.color.mix(BAND_ALPHA).filled(),
                ))
                .map_err(msg)?;
                area.draw(&Rectangle::new(
                    corners,
                    entry.color.mix(0.5).stroke_width(1),
                ))
                .map_err(msg)?;
            }
        }
        area.draw_text(&entry.label, &text, (x0 + 42, y))
            .map_err(msg)?;
        y += LEGEND_ROW;
    }
    Ok(())
}

/// Width of a legend column holding `labels`: the widest label plus the sample, within
/// `[min, 400]` pixels.
pub(super) fn legend_width<S: AsRef<str>>(
    area: &Area,
    labels: &[S],
    min: i32,
) -> Result<i32, String> {
    let style = TextStyle::from((FONT, 17).into_font());
    let widest = widest_text(area, labels, &style)?;
    Ok((widest.min(1000) as i32 + 60).clamp(min, 400))
}

/// Width in pixels of the widest of `lines` written in `style`.
fn widest_text<S: AsRef<str>>(area: &Area, lines: &[S], style: &TextStyle) -> Result<u32, String> {
    lines
        .iter()
        .map(|l| area.estimate_text_size(l.as_ref(), style).map(|(w, _)| w))
        .try_fold(0u32, |acc, w| w.map(|w| acc.max(w)))
        .map_err(msg)
}

/// Writes `note` (one line per line of the text, at most 6) in a framed white box in the top left
/// or top right corner of `area`.
pub(super) fn draw_note(area: &Area, note: &str, left: bool) -> Result<(), String> {
    let lines: Vec<String> = note.lines().take(6).map(|l| shorten(l, 80)).collect();
    if lines.is_empty() {
        return Ok(());
    }
    let style = TextStyle::from((FONT, 18).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    let widest = widest_text(area, &lines, &style)?.min(2000) as i32;
    let (pad, row, margin) = (8, 24, 10);
    let (w, h) = (widest + 2 * pad, row * lines.len() as i32 + 2 * pad - 8);
    let area_w = area.dim_in_pixel().0 as i32;
    let x0 = if left {
        margin
    } else {
        (area_w - margin - w).max(margin)
    };
    let (y0, corners) = (margin, [(x0, margin), (x0 + w, margin + h)]);
    area.draw(&Rectangle::new(corners, WHITE.mix(0.9).filled()))
        .map_err(msg)?;
    area.draw(&Rectangle::new(corners, BLACK.mix(0.4).stroke_width(1)))
        .map_err(msg)?;
    for (k, line) in lines.iter().enumerate() {
        area.draw_text(line, &style, (x0 + pad, y0 + pad + row * k as i32))
            .map_err(msg)?;
    }
    Ok(())
}
