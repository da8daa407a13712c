//! Grayscale images: owned [`Image`] and borrowed [`ImageView`] with explicit stride, bilinear
//! sampling, and PNG decode/encode. Pixel `(x, y)` has its centre at integer coordinates; `x` is
//! the column (0..width), `y` the row (0..height).

mod png_io;
mod pyramid;
mod sample;
mod texture;

pub use png_io::{PngError, read_png_gray8, read_png_gray16, write_png_gray8, write_png_gray16};
pub use pyramid::Pyramid;
pub use sample::{bilinear, bilinear_with_gradient};
pub use texture::textured_fraction;

/// An owned image of `T` pixels, row-major with `stride >= width` elements per row.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T> {
    width: usize,
    height: usize,
    stride: usize,
    data: Vec<T>,
}

/// A borrowed image: width, height, stride (elements) and the pixel slice.
#[derive(Clone, Copy, Debug)]
pub struct ImageView<'a, T> {
    width: usize,
    height: usize,
    stride: usize,
    data: &'a [T],
}

impl<T: Copy + Default> Image<T> {
    /// A `width x height` image filled with `T::default()`; stride = width.
    pub fn new(width: usize, height: usize) -> Self {
        Image {
            width,
            height,
            stride: width,
            data: vec![T::default(); width * height],
        }
    }

    /// Wraps `data` (row-major, stride = width). Panics if the length does not match.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Self {
        assert_eq!(
            data.len(),
            width * height,
            "pixel count does not match {width}x{height}"
        );
        Image {
            width,
            height,
            stride: width,
            data,
        }
    }

    /// Builds an image by evaluating `f(x, y)` at every pixel.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Image {
            width,
            height,
            stride: width,
            data,
        }
    }

    /// Re-shapes this buffer to `width x height` (stride = width) without shrinking its
    /// allocation: lets per-keyframe buffers be reused.
    pub fn resize(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.stride = width;
        self.data.resize(width * height, T::default());
    }
}

impl<T: Copy> Image<T> {
    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn stride(&self) -> usize {
        self.stride
    }
    pub fn data(&self) -> &[T] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    pub fn view(&self) -> ImageView<'_, T> {
        ImageView {
            width: self.width,
            height: self.height,
            stride: self.stride,
            data: &self.data,
        }
    }
    /// Pixel at column `x`, row `y` (panics out of bounds).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.stride + x]
    }
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: T) {
        self.data[y * self.stride + x] = v;
    }
    /// Row `y` (exactly `width` pixels).
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.stride..y * self.stride + self.width]
    }
    #[inline]
    pub fn row_mut(&mut self, y: usize) -> &mut [T] {
        let s = self.stride;
        &mut self.data[y * s..y * s + self.width]
    }
    /// Applies `f` to every pixel, producing a new image of the same size.
    pub fn map<U: Copy + Default>(&self, mut f: impl FnMut(T) -> U) -> Image<U> {
        Image::from_fn(self.width, self.height, |x, y| f(self.get(x, y)))
    }
}

impl<'a, T: Copy> ImageView<'a, T> {
    /// A view of `data` with the given geometry; `None` if `data` is too short or stride < width.
    pub fn new(width: usize, height: usize, stride: usize, data: &'a [T]) -> Option<Self> {
        let needed = if height == 0 {
            0
        } else {
            (height - 1) * stride + width
        };
        (stride >= width && data.len() >= needed).then_some(ImageView {
            width,
            height,
            stride,
            data,
        })
    }
    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn stride(&self) -> usize {
        self.stride
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> T {
        self.data[y * self.stride + x]
    }
    #[inline]
    pub fn row(&self, y: usize) -> &'a [T] {
        &self.data[y * self.stride..y * self.stride + self.width]
    }
    /// Copies into an owned, tightly packed image.
    pub fn to_owned(&self) -> Image<T>
    where
        T: Default,
    {
        Image::from_fn(self.width, self.height, |x, y| self.get(x, y))
    }
}

impl Image<u8> {
    /// Converts to `f32` grey levels (0..255).
    pub fn to_f32(&self) -> Image<f32> {
        self.map(|v| v as f32)
    }
}

impl Image<f32> {
    /// Converts to `u8`, rounding and clamping to 0..255.
    pub fn to_u8(&self) -> Image<u8> {
        self.map(|v| v.round().clamp(0.0, 255.0) as u8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_respect_stride() {
        let data: Vec<u8> = (0..20).collect();
        let v = ImageView::new(3, 4, 5, &data).unwrap();
        assert_eq!(v.get(2, 3), 17);
        assert_eq!(v.row(1), &[5, 6, 7]);
        let owned = v.to_owned();
        assert_eq!(owned.stride(), 3);
        assert_eq!(owned.get(2, 3), 17);
        assert!(ImageView::new(3, 4, 2, &data).is_none());
        assert!(ImageView::new(3, 5, 5, &data).is_none());
    }

    #[test]
    fn resize_reuses_allocation() {
        let mut im: Image<f32> = Image::new(100, 50);
        let cap = im.data.capacity();
        im.resize(50, 25);
        assert_eq!(im.data.capacity(), cap);
        assert_eq!((im.width(), im.height(), im.data().len()), (50, 25, 1250));
    }
}
