//! CRC-32 (IEEE 802.3, the checksum of PNG, zlib's `crc32` and gzip): model files carry one
//! over their archive so that a damaged file is refused at load instead of running with wrong
//! weights. It catches every single-bit error and every burst of up to 32 bits.

/// The byte-at-a-time table of the reflected polynomial `0xEDB88320`.
const TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    !bytes.iter().fold(0xFFFF_FFFFu32, |c, &b| TABLE[((c ^ b as u32) & 0xFF) as usize] ^ (c >> 8))
}

#[cfg(test)]
mod tests {
    use super::crc32;

    #[test]
    fn crc32_matches_the_standard_check_values() {
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b"IEND"), 0xAE42_6082);
    }

    #[test]
    fn crc32_sees_every_single_bit_flip() {
        let data: alloc::vec::Vec<u8> = (0..300u32).map(|i| (i * 37 % 251) as u8).collect();
        let c = crc32(&data);
        let mut d = data.clone();
        for i in 0..d.len() * 8 {
            d[i / 8] ^= 1 << (i % 8);
            assert_ne!(crc32(&d), c, "bit {i}");
            d[i / 8] ^= 1 << (i % 8);
        }
    }
}
