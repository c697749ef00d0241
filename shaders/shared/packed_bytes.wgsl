// Byte arrays packed four to a u32 word, little-endian (byte j is bits 8(j mod 4) .. of word
// j / 4): the grey images and the 8-bit cost volume as the host uploads them
// (`bytemuck::cast_slice` of a `[u8]`, src/depth/gpu.rs).

// Byte j of an array of which `word` is word j / 4.
fn packed_byte(word: u32, j: u32) -> u32 {
    return (word >> ((j & 3u) * 8u)) & 0xffu;
}
