//! Fixed-size pool of pixel buffers: frames borrow a buffer and hand it back when dropped, so the
//! steady state allocates nothing per frame.

use std::sync::{Arc, Mutex};

/// A pool of `count` buffers of `len_bytes` each, all allocated up front.
///
/// Cloning the pool clones a handle to the same buffers. When every buffer is held by the
/// consumer, [`FramePool::take`] returns `None`: backends then drop the incoming frame and count
/// it (a slow consumer loses frames, it never makes the driver allocate).
#[derive(Clone, Debug)]
pub struct FramePool {
    inner: Arc<PoolInner>,
}

#[derive(Debug)]
struct PoolInner {
    free: Mutex<Vec<Vec<u8>>>,
    len_bytes: usize,
    count: usize,
}

impl FramePool {
    /// Allocates `count` zeroed buffers of `len_bytes` each.
    pub fn new(count: usize, len_bytes: usize) -> Self {
        let free = (0..count).map(|_| vec![0u8; len_bytes]).collect();
        FramePool {
            inner: Arc::new(PoolInner {
                free: Mutex::new(free),
                len_bytes,
                count,
            }),
        }
    }

    /// Size of every buffer, bytes.
    pub fn buffer_len_bytes(&self) -> usize {
        self.inner.len_bytes
    }

    /// Number of buffers the pool owns (free or lent).
    pub fn capacity(&self) -> usize {
        self.inner.count
    }

    /// Number of buffers currently free.
    pub fn available(&self) -> usize {
        self.inner.free.lock().map(|f| f.len()).unwrap_or(0)
    }

    /// Lends a buffer, or `None` if all are in use.
    pub fn take(&self) -> Option<PooledBuffer> {
        let data = self.inner.free.lock().ok()?.pop()?;
        Some(PooledBuffer {
            data,
            pool: Arc::clone(&self.inner),
        })
    }
}

/// A buffer lent by a [`FramePool`]; returns to it on drop.
#[derive(Debug)]
pub struct PooledBuffer {
    data: Vec<u8>,
    pool: Arc<PoolInner>,
}

impl PooledBuffer {
    pub fn as_slice(&self) -> &[u8] {
        &self.data
    }

    pub fn as_mut_slice(&mut self) -> &mut [u8] {
        &mut self.data
    }
}

impl Drop for PooledBuffer {
    fn drop(&mut self) {
        let data = std::mem::take(&mut self.data);
        if let Ok(mut free) = self.pool.free.lock() {
            free.push(data);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_return_to_the_pool_and_are_reused_without_allocation() {
        let pool = FramePool::new(2, 16);
        let a = pool.take().unwrap();
        let a_ptr = a.as_slice().as_ptr();
        let b = pool.take().unwrap();
        assert!(
            pool.take().is_none(),
            "a third buffer must not be allocated"
        );
        assert_eq!(pool.available(), 0);
        drop(a);
        assert_eq!(pool.available(), 1);
        let c = pool.take().unwrap();
        assert_eq!(
            c.as_slice().as_ptr(),
            a_ptr,
            "the returned buffer is the one reused"
        );
        assert_eq!(c.as_slice().len(), 16);
        drop((b, c));
        assert_eq!(pool.available(), 2);
    }
}
