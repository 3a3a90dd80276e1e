//! The plots of `outlet eval` (detection rates, hole errors, time per stage), `outlet
//! eval --approach` and `outlet trials`, drawn with `plotters` into PNG and SVG alike,
//! and the text on `outlet sheet`.
//!
//! Text is DejaVu Sans, embedded in the binary (`fonts/`, with its licence) and drawn
//! by `ab_glyph`: no system font, fontconfig or freetype is looked for, so a plot looks
//! the same on every machine and CI. An SVG names the family `sans-serif`; its reader
//! draws it with its own. A PNG's text is rasterised here ([`GlyphBitmap`]), not by
//! plotters' own `ab_glyph` drawing, which puts each glyph at a whole pixel without its
//! side bearing: at 12-14 px its letters were unevenly spaced and its points and colons
//! stood half a line up.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
use anyhow::{Context, Result, anyhow};
use image::RgbImage;
use plotters::coord::Shift;
use plotters::coord::ranged1d::SegmentValue;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters_backend::{BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

static DEJAVU_SANS: &[u8] = include_bytes!("../fonts/DejaVuSans.ttf");

/// The family every plot's text names; the embedded font is registered under it.
pub const FONT: &str = "sans-serif";

/// Bars, and the first series of a plot.
pub const BLUE: RGBColor = RGBColor(60, 110, 200);
/// Further series.
pub const ORANGE: RGBColor = RGBColor(220, 120, 30);
pub const GREEN: RGBColor = RGBColor(40, 160, 60);
pub const PURPLE: RGBColor = RGBColor(150, 80, 180);
/// Axis labels and secondary text.
pub const GREY: RGBColor = RGBColor(90, 90, 90);
/// A bar of an empty bin.
pub const LIGHT_GREY: RGBColor = RGBColor(225, 225, 225);

/// Registers the embedded font with `plotters` (once per process).
fn register_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, DEJAVU_SANS).is_ok());
    if ok { Ok(()) } else { Err(anyhow!("the embedded font fonts/DejaVuSans.ttf could not be read")) }
}

/// A bitmap whose text `ab_glyph` lays out and rasterises at sub-pixel positions
/// (everything else is the `BitMapBackend`'s own drawing).
pub struct GlyphBitmap<'a> {
    inner: BitMapBackend<'a>,
    font: FontRef<'static>,
}

impl<'a> GlyphBitmap<'a> {
    /// Draws into `buf`, RGB rows of `size` pixels.
    pub fn with_buffer(buf: &'a mut [u8], size: (u32, u32)) -> Result<Self> {
        register_font()?;
        let font = FontRef::try_from_slice(DEJAVU_SANS).context("the embedded font fonts/DejaVuSans.ttf")?;
        Ok(Self { inner: BitMapBackend::with_buffer(buf, size), font })
    }
}

impl<'a> DrawingBackend for GlyphBitmap<'a> {
    type ErrorType = <BitMapBackend<'a> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }
    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.ensure_prepared()
    }
    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.present()
    }
    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_pixel(point, color)
    }
    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_line(from, to, style)
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }
    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_path(path, style)
    }
    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_circle(center, radius, style, fill)
    }
    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.fill_polygon(vert, style)
    }

    /// The text in the box plotters measured it by (`estimate_text_size`: the
    /// glyphs' advances wide), placed by its anchor and turned by its transform;
    /// the baseline divides the box's height as the font's ascent and descent do.
    fn draw_text<S: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let colour = style.color();
        if colour.alpha == 0.0 {
            return Ok(());
        }
        let ((x0, y0), (x1, y1)) = style.layout_box(text).map_err(|e| DrawingErrorKind::FontError(Box::new(e)))?;
        let (width, height) = (x1 - x0, y1 - y0);
        let dx = match style.anchor().h_pos {
            HPos::Left => 0,
            HPos::Right => -width,
            HPos::Center => -width / 2,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0,
            VPos::Center => -height / 2,
            VPos::Bottom => -height,
        };
        let transform = style.transform();
        let (w, h) = self.inner.get_size();
        let font = self.font.as_scaled(PxScale::from(style.size() as f32));
        let baseline = height as f32 * font.ascent() / (font.ascent() - font.descent());
        let inner = &mut self.inner;
        let (mut caret, mut previous) = (0.0f32, None);
        for c in text.chars() {
            let id = font.glyph_id(c);
            if let Some(p) = previous {
                caret += font.kern(p, id);
            }
            previous = Some(id);
            let glyph = id.with_scale_and_position(font.scale(), ab_glyph::point(caret, baseline));
            caret += font.h_advance(id);
            let Some(outline) = self.font.outline_glyph(glyph) else { continue };
            let bounds = outline.px_bounds();
            let mut result = Ok(());
            outline.draw(|gx, gy, coverage| {
                if result.is_err() || coverage <= 0.0 {
                    return;
                }
                let local = (bounds.min.x as i32 + gx as i32 + dx, bounds.min.y as i32 + gy as i32 + dy);
                let (x, y) = transform.transform(local.0, local.1);
                let (x, y) = (pos.0 + x, pos.1 + y);
                if x >= 0 && y >= 0 && x < w as i32 && y < h as i32 {
                    let alpha = colour.alpha * f64::from(coverage.min(1.0));
                    result = inner.draw_pixel((x, y), BackendColor { alpha, rgb: colour.rgb });
                }
            });
            result?;
        }
        Ok(())
    }
}

/// What drawing into a backend `DB` returns.
pub type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A plot drawn the same way into any backend (PNG and SVG).
pub trait Figure {
    /// Width and height: the PNG's pixels, the SVG's user units.
    fn size(&self) -> (u32, u32);
    /// Draws onto `root`, already filled white.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

fn drawing_error<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow!("drawing a plot: {e}")
}

/// The figure as an RGB image.
pub fn render_png(figure: &impl Figure) -> Result<RgbImage> {
    register_font()?;
    let (w, h) = figure.size();
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    {
        let root = GlyphBitmap::with_buffer(&mut buf, (w, h))?.into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error)?;
        figure.draw(&root).map_err(drawing_error)?;
        root.present().map_err(drawing_error)?;
    }
    RgbImage::from_raw(w, h, buf).context("a plot's pixels do not fill its size")
}

/// The figure as an SVG document.
pub fn render_svg(figure: &impl Figure) -> Result<String> {
    register_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, figure.size()).into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error)?;
        figure.draw(&root).map_err(drawing_error)?;
        root.present().map_err(drawing_error)?;
    }
    Ok(svg)
}

/// Writes the figure as `DIR/STEM.png` and `DIR/STEM.svg`; returns both paths.
pub fn write(figure: &impl Figure, dir: &Path, stem: &str) -> Result<[PathBuf; 2]> {
    let png = dir.join(format!("{stem}.png"));
    let svg = dir.join(format!("{stem}.svg"));
    render_png(figure)?
        .save_with_format(&png, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", png.display()))?;
    std::fs::write(&svg, render_svg(figure)?).with_context(|| format!("writing {}", svg.display()))?;
    Ok([png, svg])
}

/// Writes the figure as a PNG at `path` (its SVG beside it, same stem), making its folder.
pub fn write_at(figure: &impl Figure, path: &Path) -> Result<[PathBuf; 2]> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "plot".into());
    write(figure, dir, &stem)
}

/// Text in the embedded font on an image (the scenario names of `outlet sheet`),
/// top left at `(x, y)`, `size_px` high.
pub fn draw_label(img: &mut RgbImage, text: &str, (x, y): (i32, i32), size_px: f64, colour: RGBColor) -> Result<()> {
    register_font()?;
    let size = img.dimensions();
    let root = GlyphBitmap::with_buffer(img.as_mut(), size)?.into_drawing_area();
    let style = TextStyle::from((FONT, size_px).into_font()).color(&colour);
    root.draw_text(text, &style, (x, y)).map_err(drawing_error)?;
    root.present().map_err(drawing_error)
}

/// One bar of a rate chart: its label, the rate (0..1) and the number of trials.
#[derive(Debug, Clone, PartialEq)]
pub struct RateBar {
    pub label: String,
    pub rate: f64,
    pub n: usize,
}

/// A bar chart of rates (0-100%) over labelled bins, titled, each bar with its rate
/// and its count written on it (bars near 100% look alike). Bin labels get smaller
/// until they fit their bars.
pub fn rate_bars<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    bars: &[RateBar],
) -> DrawResult<DB> {
    let n = bars.len().max(1) as u32;
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 18))
        .margin(8)
        .x_label_area_size(44)
        .y_label_area_size(52)
        .build_cartesian_2d((0u32..n - 1).into_segmented(), 0.0..100.0f64)?;
    let bar_px = area.dim_in_pixel().0.saturating_sub(70) / n;
    let longest = bars.iter().map(|b| b.label.as_str()).max_by_key(|l| l.len()).unwrap_or("");
    let mut label_size = 14.0;
    while label_size > 8.0
        && area.estimate_text_size(longest, &(FONT, label_size).into_text_style(area))?.0 + 4 > bar_px
    {
        label_size -= 1.0;
    }
    let label_of = |v: &SegmentValue<u32>| match v {
        SegmentValue::CenterOf(i) => bars.get(*i as usize).map(|b| b.label.clone()).unwrap_or_default(),
        _ => String::new(),
    };
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(bars.len() + 1)
        .x_label_formatter(&label_of)
        .x_label_style((FONT, label_size))
        .y_label_formatter(&|v| format!("{v:.0}%"))
        .y_labels(6)
        .y_label_style((FONT, 13))
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style((FONT, 14))
        .light_line_style(WHITE)
        .draw()?;
    let margin = (bar_px / 10).clamp(2, 10);
    chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
        let colour = if b.n == 0 { LIGHT_GREY } else { BLUE };
        let top = (b.rate * 100.0).clamp(0.0, 100.0);
        let mut bar = Rectangle::new(
            [(SegmentValue::Exact(i as u32), 0.0), (SegmentValue::Exact(i as u32 + 1), top)],
            colour.filled(),
        );
        bar.set_margin(0, 0, margin, margin);
        bar
    }))?;
    let small = (FONT, 12).into_font();
    for (i, b) in bars.iter().enumerate() {
        let x = SegmentValue::CenterOf(i as u32);
        let top = (b.rate * 100.0).clamp(0.0, 100.0);
        // The rate inside the bar's top, or above a short bar; the count at its foot.
        if b.n > 0 {
            let (y, dy, colour, v) =
                if top > 15.0 { (top, 4, WHITE, VPos::Top) } else { (top, -4, BLACK, VPos::Bottom) };
            let style = small.color(&colour).pos(Pos::new(HPos::Center, v));
            chart.draw_series(std::iter::once(
                EmptyElement::at((x.clone(), y)) + Text::new(format!("{:.1}%", 100.0 * b.rate), (0, dy), style),
            ))?;
        }
        let colour = if top > 15.0 { WHITE } else { GREY };
        let style = small.color(&colour).pos(Pos::new(HPos::Center, VPos::Bottom));
        chart.draw_series(std::iter::once(
            EmptyElement::at((x, 0.0)) + Text::new(format!("n={}", b.n), (0, -4), style),
        ))?;
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    struct Bars(Vec<RateBar>);

    impl Figure for Bars {
        fn size(&self) -> (u32, u32) {
            (420, 300)
        }
        fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
            rate_bars(root, "success vs light", "lighting", "share inserted", &self.0)
        }
    }

    fn bars() -> Bars {
        Bars(vec![
            RateBar { label: "dim".into(), rate: 0.25, n: 8 },
            RateBar { label: "bright".into(), rate: 0.975, n: 40 },
            RateBar { label: "none".into(), rate: 0.0, n: 0 },
        ])
    }

    /// The share of a region's pixels that pass `test`.
    fn share(img: &RgbImage, x: std::ops::Range<u32>, y: std::ops::Range<u32>, test: impl Fn([u8; 3]) -> bool) -> f64 {
        let (mut hits, mut all) = (0usize, 0usize);
        for yy in y {
            for xx in x.clone() {
                hits += test(img.get_pixel(xx, yy).0) as usize;
                all += 1;
            }
        }
        hits as f64 / all.max(1) as f64
    }

    /// The share of a region's pixels of about this colour.
    pub(crate) fn share_of(img: &RgbImage, colour: RGBColor, x: std::ops::Range<u32>, y: std::ops::Range<u32>) -> f64 {
        share(img, x, y, |p| p.iter().zip([colour.0, colour.1, colour.2]).all(|(a, b)| a.abs_diff(b) < 12))
    }

    /// The share of a region's pixels darker than mid-grey: text on white, anti-aliased.
    pub(crate) fn ink(img: &RgbImage, x: std::ops::Range<u32>, y: std::ops::Range<u32>) -> f64 {
        share(img, x, y, |p| p.iter().map(|c| u32::from(*c)).sum::<u32>() < 3 * 128)
    }

    #[test]
    fn a_rate_chart_draws_its_bars_to_their_height_in_png_and_names_them_in_svg() {
        let figure = bars();
        let img = render_png(&figure).expect("png");
        assert_eq!(img.dimensions(), (420, 300));
        // The tall bar (the middle third) is much bluer than the short one (the left third).
        let (w, h) = img.dimensions();
        let tall = share_of(&img, BLUE, w / 3..2 * w / 3, 40..h - 60);
        let short = share_of(&img, BLUE, 60..w / 3, 40..h - 60);
        assert!(tall > 0.3 && short < tall / 2.0, "tall {tall:.2} short {short:.2}");
        // Text was drawn in the real font: dark anti-aliased pixels in the title's band.
        let title = ink(&img, 0..w, 0..24);
        assert!(title > 0.01, "title band {title:.3}");
        let svg = render_svg(&figure).expect("svg");
        for text in ["success vs light", "bright", "97.5%", "n=40", "n=0", "lighting", "share inserted"] {
            assert!(svg.contains(text), "{text} missing from the SVG");
        }
    }

    #[test]
    fn write_at_puts_a_png_and_an_svg_beside_each_other_in_a_new_folder() {
        let dir = tempfile::tempdir().expect("tmp");
        let [png, svg] = write_at(&bars(), &dir.path().join("plots/trials.png")).expect("write");
        assert_eq!(png, dir.path().join("plots/trials.png"));
        assert_eq!(svg, dir.path().join("plots/trials.svg"));
        assert_eq!(image::open(&png).expect("decodes").to_rgb8().dimensions(), (420, 300));
        assert!(std::fs::read_to_string(&svg).expect("svg").starts_with("<svg"));
    }

    #[test]
    fn a_label_is_drawn_where_asked_and_nowhere_else() {
        let mut img = RgbImage::from_pixel(200, 60, image::Rgb([24, 24, 24]));
        draw_label(&mut img, "white2x2", (10, 20), 16.0, RGBColor(235, 235, 235)).expect("label");
        let bright = |x, y| share(&img, x, y, |p| p.iter().all(|c| *c > 128));
        let (inside, outside) = (bright(10..90, 20..36), bright(100..200, 0..60));
        assert!(inside > 0.05 && outside == 0.0, "inside {inside:.3} outside {outside:.3}");
    }
}
