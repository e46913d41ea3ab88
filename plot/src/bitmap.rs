//! What an SVG's maps carry in few bytes (issue 47: a 121-point study's page weighed 1 MB):
//! each colour map an embedded PNG of viridis' 256 levels (a few kilobytes, smoothed by the
//! browser, where a rectangle per cell weighed about 160 kB and showed its cells), and each map's
//! design points one path (where plotters writes two circles a point). Plotters draws a
//! placeholder rectangle where each map goes; [`embed`] puts the image in its place and the
//! points on top.

use base64::Engine;
use plotters::style::RGBColor;

use crate::PlotError;
use crate::colour::viridis;

/// The maps and points of an SVG, collected while plotters draws the rest.
#[derive(Debug, Default)]
pub(crate) struct Embedded {
    /// In drawing order, as their placeholders.
    pub bitmaps: Vec<Bitmap>,
    /// The design points' pixels on every map, drawn over everything else.
    pub markers: Vec<(i32, i32)>,
}

/// A design point's marker: a white disc with a black ring.
pub(crate) const MARKER_RADIUS: i32 = 3;

/// The fill that marks where a bitmap goes: no picture paints with it (viridis never gets this dark).
pub(crate) const PLACEHOLDER: RGBColor = RGBColor(1, 2, 3);
const PLACEHOLDER_FILL: &str = "fill=\"#010203\"";

/// Pixels, rows from the top, a level of viridis (0 to 255) a pixel.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Bitmap {
    width: u32,
    height: u32,
    levels: Vec<u8>,
}

impl Bitmap {
    /// Each pixel viridis at `at(u, v)` (in [0, 1]) of its centre, u and v in (0, 1) from the top left.
    pub fn paint(width: u32, height: u32, at: impl Fn(f64, f64) -> f64) -> Bitmap {
        let mut levels = Vec::with_capacity(width as usize * height as usize);
        for j in 0..height {
            for i in 0..width {
                let t = at((i as f64 + 0.5) / width as f64, (j as f64 + 0.5) / height as f64);
                levels.push((if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 } * 255.0).round() as u8);
            }
        }
        Bitmap { width, height, levels }
    }

    fn png(&self) -> Result<Vec<u8>, PlotError> {
        let palette: Vec<u8> = (0..=255)
            .flat_map(|k| {
                let c = viridis(k as f64 / 255.0);
                [c.0, c.1, c.2]
            })
            .collect();
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
        encoder.set_color(png::ColorType::Indexed);
        encoder.set_palette(palette);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Best);
        let mut writer = encoder.write_header().map_err(|e| PlotError::Draw(e.to_string()))?;
        writer.write_image_data(&self.levels).map_err(|e| PlotError::Draw(e.to_string()))?;
        writer.finish().map_err(|e| PlotError::Draw(e.to_string()))?;
        Ok(bytes)
    }
}

/// `svg` with each placeholder rectangle, in order, replaced by its bitmap as an `<image>` that
/// fills the rectangle's place, and the markers on top.
pub(crate) fn embed(svg: &str, embedded: &Embedded) -> Result<String, PlotError> {
    let mut out = String::with_capacity(svg.len());
    let mut rest = svg;
    for bitmap in &embedded.bitmaps {
        let missing = || PlotError::Draw("a colour map's place is missing from the SVG".into());
        let fill = rest.find(PLACEHOLDER_FILL).ok_or_else(missing)?;
        let start = rest[..fill].rfind("<rect").ok_or_else(missing)?;
        let end = fill + rest[fill..].find("/>").ok_or_else(missing)? + 2;
        let rect = &rest[start..end];
        let attribute = |name: &str| -> Result<&str, PlotError> {
            let key = format!(" {name}=\"");
            let at = rect.find(&key).ok_or_else(missing)? + key.len();
            Ok(&rect[at..at + rect[at..].find('"').ok_or_else(missing)?])
        };
        out.push_str(&rest[..start]);
        out.push_str(&format!(
            "<image x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" preserveAspectRatio=\"none\" href=\"data:image/png;base64,{}\"/>",
            attribute("x")?,
            attribute("y")?,
            attribute("width")?,
            attribute("height")?,
            base64::engine::general_purpose::STANDARD.encode(bitmap.png()?)
        ));
        rest = &rest[end..];
    }
    let close = rest.rfind("</svg>").ok_or_else(|| PlotError::Draw("an SVG without its end".into()))?;
    out.push_str(&rest[..close]);
    if !embedded.markers.is_empty() {
        // a circle as two half arcs from its left end
        let (r, d) = (MARKER_RADIUS, 2 * MARKER_RADIUS);
        let path: String = embedded
            .markers
            .iter()
            .map(|(x, y)| format!("M{},{}a{r},{r} 0 1,0 {d},0a{r},{r} 0 1,0 -{d},0", x - r, y))
            .collect();
        out.push_str(&format!("<path fill=\"#FFFFFF\" stroke=\"#000000\" stroke-width=\"1\" d=\"{path}\"/>\n"));
    }
    out.push_str(&rest[close..]);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_placeholder_becomes_its_bitmap_in_order() {
        let svg = r##"<svg><rect x="1" y="2" width="30" height="40" opacity="1" fill="#010203" stroke="none"/><circle/><rect x="5" y="6" width="7" height="8" opacity="1" fill="#010203" stroke="none"/></svg>"##;
        let top = Bitmap::paint(2, 3, |_, _| 1.0);
        let ramp = Bitmap::paint(4, 1, |u, _| u);
        assert_eq!(ramp.levels, [32, 96, 159, 223], "pixel centres at 1/8, 3/8, ...");
        let markers = vec![(10, 20), (30, 40)];
        let out = embed(svg, &Embedded { bitmaps: vec![top.clone(), ramp], markers }).unwrap();
        assert!(!out.contains("<rect"), "{out}");
        assert!(out.starts_with("<svg><image x=\"1\" y=\"2\" width=\"30\" height=\"40\" preserveAspectRatio=\"none\" href=\"data:image/png;base64,iVBORw0KGgo"), "{out}");
        assert!(out.contains("\"/><circle/><image x=\"5\" y=\"6\" width=\"7\" height=\"8\""), "{out}");
        // the points over everything, one path
        assert!(
            out.ends_with(" d=\"M7,20a3,3 0 1,0 6,0a3,3 0 1,0 -6,0M27,40a3,3 0 1,0 6,0a3,3 0 1,0 -6,0\"/>\n</svg>"),
            "{out}"
        );
        // the PNG decodes to the pixels painted
        let data = out.split("base64,").nth(1).unwrap().split('"').next().unwrap();
        let png = base64::engine::general_purpose::STANDARD.decode(data).unwrap();
        let mut reader = png::Decoder::new(&png[..]).read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut pixels).unwrap();
        assert_eq!((info.width, info.height), (2, 3));
        assert_eq!(pixels[..info.buffer_size()], [255; 6], "the top level");
        let palette = reader.info().palette.as_ref().unwrap();
        assert_eq!(
            palette[3 * 255..],
            {
                let c = viridis(1.0);
                [c.0, c.1, c.2]
            },
            "of viridis"
        );
        // a bitmap without its place is an error, not a picture without its map
        assert!(embed("<svg></svg>", &Embedded { bitmaps: vec![top], markers: Vec::new() }).is_err());
    }
}
