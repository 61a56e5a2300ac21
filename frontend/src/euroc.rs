//! EuRoC/ASL dataset folders: why this exists is that the public
//! visual-inertial datasets come in this layout, and a user with one should
//! be able to run the front-end on it. A camera is `mav0/cam0/`: `data.csv`
//! (`#timestamp [ns],filename`) and `data/*.png`, 8-bit grey (colour images
//! are reduced to their luma).

use std::path::{Path, PathBuf};

use crate::image::Gray;

/// Errors reading a dataset, each naming the file.
#[derive(Debug, thiserror::Error)]
pub enum EurocError {
    #[error("cannot read '{0}': {1}")]
    Io(PathBuf, std::io::Error),
    #[error("'{0}', line {1}: {2}")]
    BadLine(PathBuf, usize, String),
    #[error("'{0}': {1}")]
    BadImage(PathBuf, String),
}

/// One camera frame of the dataset: its time (ns) and image file.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameEntry {
    pub t_ns: u64,
    pub path: PathBuf,
}

/// The frames of camera `cam` (`mav0/cam{cam}`) in time order.
pub fn frames(root: &Path, cam: u32) -> Result<Vec<FrameEntry>, EurocError> {
    let dir = root.join("mav0").join(format!("cam{cam}"));
    let csv = dir.join("data.csv");
    let text = std::fs::read_to_string(&csv).map_err(|e| EurocError::Io(csv.clone(), e))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut it = line.split(',').map(str::trim);
        let (Some(t), Some(name)) = (it.next(), it.next()) else {
            return Err(EurocError::BadLine(csv, i + 1, "expected 'timestamp,filename'".into()));
        };
        let t_ns = t
            .parse::<u64>()
            .map_err(|e| EurocError::BadLine(csv.clone(), i + 1, format!("timestamp '{t}': {e}")))?;
        out.push(FrameEntry {
            t_ns,
            path: dir.join("data").join(name),
        });
    }
    out.sort_by_key(|f| f.t_ns);
    Ok(out)
}

/// Reads an 8-bit PNG as grey (RGB and RGBA reduced to luma, BT.601).
pub fn read_png(path: &Path) -> Result<Gray, EurocError> {
    let bad = |m: String| EurocError::BadImage(path.to_path_buf(), m);
    let file = std::fs::File::open(path).map_err(|e| EurocError::Io(path.to_path_buf(), e))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec.read_info().map_err(|e| bad(e.to_string()))?;
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(e.to_string()))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let bytes = &buf[..info.buffer_size()];
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err(bad("indexed colour after expansion".into())),
    };
    if bytes.len() != w * h * channels {
        return Err(bad(format!("{} bytes for {w}×{h}×{channels}", bytes.len())));
    }
    let px: Vec<f32> = bytes
        .chunks_exact(channels)
        .map(|c| match channels {
            1 | 2 => f32::from(c[0]),
            _ => 0.299 * f32::from(c[0]) + 0.587 * f32::from(c[1]) + 0.114 * f32::from(c[2]),
        })
        .collect();
    Ok(Gray {
        width: w,
        height: h,
        px,
    })
}

/// Writes `g` as an 8-bit grey PNG (for tests and for looking at frames).
pub fn write_png(path: &Path, g: &Gray) -> Result<(), EurocError> {
    let file = std::fs::File::create(path).map_err(|e| EurocError::Io(path.to_path_buf(), e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), g.width as u32, g.height as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let bytes: Vec<u8> = g.px.iter().map(|v| v.round().clamp(0.0, 255.0) as u8).collect();
    let mut w = enc
        .write_header()
        .map_err(|e| EurocError::BadImage(path.to_path_buf(), e.to_string()))?;
    w.write_image_data(&bytes)
        .map_err(|e| EurocError::BadImage(path.to_path_buf(), e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_dataset_folder() {
        let dir = tempfile::tempdir().unwrap();
        let cam = dir.path().join("mav0/cam0/data");
        std::fs::create_dir_all(&cam).unwrap();
        let g = crate::synthetic::textured(64, 48, 1, 0.0, 0.0);
        write_png(&cam.join("200.png"), &g).unwrap();
        write_png(&cam.join("100.png"), &g).unwrap();
        std::fs::write(
            dir.path().join("mav0/cam0/data.csv"),
            "#timestamp [ns],filename\n200,200.png\n100,100.png\n",
        )
        .unwrap();
        let f = frames(dir.path(), 0).unwrap();
        assert_eq!(f.iter().map(|f| f.t_ns).collect::<Vec<_>>(), vec![100, 200]);
        let back = read_png(&f[0].path).unwrap();
        assert_eq!((back.width, back.height), (64, 48));
        assert!(back.px.iter().zip(&g.px).all(|(a, b)| (a - b.round()).abs() < 0.5));
        std::fs::write(dir.path().join("mav0/cam0/data.csv"), "abc,1.png\n").unwrap();
        assert!(frames(dir.path(), 0).unwrap_err().to_string().contains("line 1"));
    }
}
