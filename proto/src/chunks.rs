//! Solution files travel as streams of `SolutionChunk`s: cutting them up, and putting them back
//! together with every check a receiver needs (order, sizes, truncation), on both ends.

use crate::v1::SolutionChunk;

/// Largest payload of one `SolutionChunk` (1 MiB): with its few framing bytes a chunk message
/// stays far below gRPC's default 4 MiB message limit.
pub const CHUNK_BYTES: usize = 1 << 20;

/// Splits `bytes` into the chunks of a stream, in order (none for an empty input).
pub fn chunks(bytes: &[u8]) -> impl Iterator<Item = SolutionChunk> + '_ {
    let total = bytes.len() as u64;
    bytes.chunks(CHUNK_BYTES).enumerate().map(move |(i, data)| SolutionChunk {
        offset: (i * CHUNK_BYTES) as u64,
        data: data.to_vec(),
        total_bytes: total,
    })
}

/// Why a chunk stream was refused; each variant gives the numbers involved.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChunkError {
    /// The announced size exceeds what the receiver accepts.
    #[error("solution of {announced} bytes exceeds the limit of {limit} bytes")]
    TooLarge {
        /// Announced total size.
        announced: u64,
        /// The receiver's limit.
        limit: u64,
    },
    /// A chunk larger than [`CHUNK_BYTES`].
    #[error("solution chunk at offset {offset} has {len} bytes, more than the {CHUNK_BYTES} allowed")]
    ChunkTooLarge {
        /// Offset of the chunk.
        offset: u64,
        /// Its payload size.
        len: usize,
    },
    /// A chunk that does not start where the previous one ended (lost or reordered chunk).
    #[error("solution chunk at offset {found}, expected offset {expected}")]
    Gap {
        /// Offset expected from the bytes received so far.
        expected: u64,
        /// Offset of the chunk received.
        found: u64,
    },
    /// A chunk announcing another total size than the stream.
    #[error("solution chunk announces {found} bytes in all, the stream {expected}")]
    TotalChanged {
        /// The stream's announced size.
        expected: u64,
        /// The chunk's.
        found: u64,
    },
    /// More bytes than announced.
    #[error("solution stream carries more than the {announced} bytes announced")]
    Overflow {
        /// The announced size.
        announced: u64,
    },
    /// The stream ended before all announced bytes came.
    #[error("solution stream is truncated: {received} of {announced} bytes received")]
    Truncated {
        /// Bytes received.
        received: u64,
        /// Bytes announced.
        announced: u64,
    },
}

/// Puts a chunk stream back together.
#[derive(Debug)]
pub struct Assembler {
    announced: u64,
    bytes: Vec<u8>,
}

impl Assembler {
    /// A receiver of `announced` bytes; refuses more than `limit` up front.
    pub fn new(announced: u64, limit: u64) -> Result<Self, ChunkError> {
        if announced > limit {
            return Err(ChunkError::TooLarge { announced, limit });
        }
        // Grow with the data actually received: the announcement comes from a peer.
        let reserve = announced.min(CHUNK_BYTES as u64) as usize;
        Ok(Self { announced, bytes: Vec::with_capacity(reserve) })
    }

    /// Appends the next chunk, checking its place in the stream.
    pub fn push(&mut self, chunk: SolutionChunk) -> Result<(), ChunkError> {
        let received = self.bytes.len() as u64;
        if chunk.data.len() > CHUNK_BYTES {
            return Err(ChunkError::ChunkTooLarge { offset: chunk.offset, len: chunk.data.len() });
        }
        if chunk.total_bytes != self.announced {
            return Err(ChunkError::TotalChanged { expected: self.announced, found: chunk.total_bytes });
        }
        if chunk.offset != received {
            return Err(ChunkError::Gap { expected: received, found: chunk.offset });
        }
        if received + chunk.data.len() as u64 > self.announced {
            return Err(ChunkError::Overflow { announced: self.announced });
        }
        self.bytes.extend_from_slice(&chunk.data);
        Ok(())
    }

    /// Bytes received so far.
    pub fn received(&self) -> u64 {
        self.bytes.len() as u64
    }

    /// The whole payload, once every announced byte came.
    pub fn finish(self) -> Result<Vec<u8>, ChunkError> {
        let received = self.bytes.len() as u64;
        if received < self.announced {
            return Err(ChunkError::Truncated { received, announced: self.announced });
        }
        Ok(self.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn payload(len: usize) -> Vec<u8> {
        (0..len).map(|i| (i % 251) as u8).collect()
    }

    #[test]
    fn round_trip_across_chunk_boundaries() {
        for len in [0, 1, CHUNK_BYTES - 1, CHUNK_BYTES, CHUNK_BYTES + 1, 3 * CHUNK_BYTES + 17] {
            let bytes = payload(len);
            let pieces: Vec<_> = chunks(&bytes).collect();
            assert_eq!(pieces.len(), len.div_ceil(CHUNK_BYTES), "{len}");
            assert!(pieces.iter().all(|c| c.data.len() <= CHUNK_BYTES && c.total_bytes == len as u64));
            let mut asm = Assembler::new(len as u64, 1 << 30).unwrap();
            for c in pieces {
                asm.push(c).unwrap();
            }
            assert_eq!(asm.finish().unwrap(), bytes);
        }
    }

    #[test]
    fn damaged_streams_are_refused_with_their_numbers() {
        let bytes = payload(2 * CHUNK_BYTES + 5);
        let pieces: Vec<_> = chunks(&bytes).collect();
        let total = bytes.len() as u64;

        let mut asm = Assembler::new(total, 1 << 30).unwrap();
        asm.push(pieces[0].clone()).unwrap();
        assert_eq!(asm.finish().unwrap_err(), ChunkError::Truncated { received: CHUNK_BYTES as u64, announced: total });

        let mut asm = Assembler::new(total, 1 << 30).unwrap();
        asm.push(pieces[0].clone()).unwrap();
        let err = asm.push(pieces[2].clone()).unwrap_err();
        assert_eq!(err, ChunkError::Gap { expected: CHUNK_BYTES as u64, found: 2 * CHUNK_BYTES as u64 });

        let mut asm = Assembler::new(total, 1 << 30).unwrap();
        let mut other = pieces[0].clone();
        other.total_bytes += 1;
        assert_eq!(asm.push(other).unwrap_err(), ChunkError::TotalChanged { expected: total, found: total + 1 });

        let mut asm = Assembler::new(3, 1 << 30).unwrap();
        let err = asm.push(SolutionChunk { offset: 0, data: vec![0; 4], total_bytes: 3 }).unwrap_err();
        assert_eq!(err, ChunkError::Overflow { announced: 3 });

        let mut asm = Assembler::new(total, 1 << 30).unwrap();
        let err =
            asm.push(SolutionChunk { offset: 0, data: vec![0; CHUNK_BYTES + 1], total_bytes: total }).unwrap_err();
        assert_eq!(err, ChunkError::ChunkTooLarge { offset: 0, len: CHUNK_BYTES + 1 });

        assert_eq!(Assembler::new(11, 10).unwrap_err(), ChunkError::TooLarge { announced: 11, limit: 10 });
    }
}
