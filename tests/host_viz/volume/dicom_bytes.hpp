#pragma once
// Tiny DICOM Part 10 files built byte by byte, for the scan and loader tests: a data set in
// explicit or implicit VR, little or big endian, with sequences and compressed fragments; and
// in-place edits of a real file (a field's value, PixelData's length). Test-only.

#include <cstdint>
#include <random>
#include <string>
#include <string_view>
#include <vector>

namespace lancet::test {

class DicomDataSet {
 public:
  DicomDataSet(bool explicit_vr = true, bool big_endian = false) : explicit_(explicit_vr), big_(big_endian) {}

  /// One element; a string value is padded to even length with `pad`.
  DicomDataSet& element(std::uint16_t g, std::uint16_t e, std::string_view vr, std::string value, char pad = ' ') {
    if (value.size() % 2 == 1) value += pad;
    header(g, e, vr, static_cast<std::uint32_t>(value.size()));
    bytes_ += value;
    return *this;
  }
  DicomDataSet& text(std::uint16_t g, std::uint16_t e, std::string_view vr, std::string value) { return element(g, e, vr, std::move(value)); }
  DicomDataSet& uid(std::uint16_t g, std::uint16_t e, std::string value) { return element(g, e, "UI", std::move(value), '\0'); }
  DicomDataSet& us(std::uint16_t g, std::uint16_t e, std::uint16_t v) { return element(g, e, "US", u16(v)); }
  /// A sequence of undefined length holding `items` (each a data set in this encoding).
  DicomDataSet& sequence(std::uint16_t g, std::uint16_t e, const std::vector<DicomDataSet>& items) {
    header(g, e, "SQ", 0xFFFFFFFFu);
    for (const DicomDataSet& item : items) {
      tag(0xFFFE, 0xE000);
      bytes_ += u32(static_cast<std::uint32_t>(item.bytes().size()));
      bytes_ += item.bytes();
    }
    tag(0xFFFE, 0xE0DD);
    bytes_ += u32(0);
    return *this;
  }
  /// Native pixel data of `bytes` bytes (OW), values 0, 1, 2, ...
  DicomDataSet& pixels(std::size_t bytes) {
    std::string v(bytes, '\0');
    for (std::size_t i = 0; i < bytes; ++i) v[i] = static_cast<char>(i * 7);
    return element(0x7FE0, 0x0010, "OW", v, '\0');
  }
  /// Compressed pixel data: an empty basic offset table and the given fragments.
  DicomDataSet& fragments(const std::vector<std::string>& frags) {
    header(0x7FE0, 0x0010, "OB", 0xFFFFFFFFu);
    tag(0xFFFE, 0xE000);
    bytes_ += u32(0);
    for (const std::string& f : frags) {
      tag(0xFFFE, 0xE000);
      bytes_ += u32(static_cast<std::uint32_t>(f.size()));
      bytes_ += f;
    }
    tag(0xFFFE, 0xE0DD);
    bytes_ += u32(0);
    return *this;
  }
  DicomDataSet& raw(std::string_view b) {
    bytes_ += b;
    return *this;
  }
  [[nodiscard]] const std::string& bytes() const { return bytes_; }

  std::string u16(std::uint16_t v) const {
    return big_ ? std::string{static_cast<char>(v >> 8), static_cast<char>(v & 0xFF)}
                : std::string{static_cast<char>(v & 0xFF), static_cast<char>(v >> 8)};
  }
  std::string u32(std::uint32_t v) const {
    std::string s(4, '\0');
    for (int i = 0; i < 4; ++i) s[static_cast<std::size_t>(big_ ? 3 - i : i)] = static_cast<char>((v >> (8 * i)) & 0xFF);
    return s;
  }

 private:
  void tag(std::uint16_t g, std::uint16_t e) { bytes_ += u16(g) + u16(e); }
  void header(std::uint16_t g, std::uint16_t e, std::string_view vr, std::uint32_t len) {
    tag(g, e);
    if (!explicit_) {
      bytes_ += u32(len);
      return;
    }
    bytes_ += vr;
    constexpr std::string_view kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN", "UR", "UT", "UV"};
    bool is_long = false;
    for (auto l : kLong) is_long = is_long || l == vr;
    if (is_long) bytes_ += std::string(2, '\0') + u32(len);
    else bytes_ += u16(static_cast<std::uint16_t>(len));
  }

  bool explicit_, big_;
  std::string bytes_;
};

/// Preamble, 'DICM', the file meta group (explicit VR little endian) naming `transfer_syntax`,
/// then `data_set`.
inline std::string dicom_file(const std::string& transfer_syntax, const DicomDataSet& data_set) {
  DicomDataSet meta;
  meta.element(0x0002, 0x0001, "OB", std::string("\0\1", 2), '\0');
  meta.uid(0x0002, 0x0002, "1.2.840.10008.5.1.4.1.1.2");
  meta.uid(0x0002, 0x0003, "1.2.3.4.5.6.7");
  meta.uid(0x0002, 0x0010, transfer_syntax);
  DicomDataSet group_length;
  group_length.element(0x0002, 0x0000, "UL", group_length.u32(static_cast<std::uint32_t>(meta.bytes().size())));
  return std::string(128, '\0') + "DICM" + group_length.bytes() + meta.bytes() + data_set.bytes();
}

/// A small CT slice data set: Rows × Columns 16-bit signed pixels at z mm along the normal of an
/// axial orientation, 0.5 mm pixels, in series `series_uid` (pixels: byte count of PixelData; -1
/// for the full Rows × Columns × 2).
inline DicomDataSet ct_slice(bool explicit_vr, bool big_endian, double z_mm, const std::string& series_uid, int rows = 3,
                             int columns = 4, const std::string& modality = "CT", long pixels = -1) {
  DicomDataSet d(explicit_vr, big_endian);
  d.text(0x0008, 0x0060, "CS", modality);
  d.uid(0x0020, 0x000E, series_uid);
  d.text(0x0020, 0x0032, "DS", "-10\\-20\\" + std::to_string(z_mm));
  d.text(0x0020, 0x0037, "DS", "1\\0\\0\\0\\1\\0");
  d.us(0x0028, 0x0002, 1);
  d.text(0x0028, 0x0004, "CS", "MONOCHROME2");
  d.us(0x0028, 0x0010, static_cast<std::uint16_t>(rows));
  d.us(0x0028, 0x0011, static_cast<std::uint16_t>(columns));
  d.text(0x0028, 0x0030, "DS", "0.5\\0.5");
  d.us(0x0028, 0x0100, 16);
  d.us(0x0028, 0x0101, 16);
  d.us(0x0028, 0x0102, 15);
  d.us(0x0028, 0x0103, 1);
  d.text(0x0028, 0x1052, "DS", "-1024");
  d.text(0x0028, 0x1053, "DS", "1");
  d.pixels(pixels < 0 ? static_cast<std::size_t>(rows * columns * 2) : static_cast<std::size_t>(pixels));
  return d;
}

/// The offset of the first occurrence of `needle` in `bytes` (npos when absent).
/// The seeds of the mutation tests: one CT slice in each transfer syntax (explicit VR little
/// endian, implicit VR little endian, explicit VR big endian).
inline std::vector<std::string> slice_in_every_syntax() {
  return {dicom_file("1.2.840.10008.1.2.1", ct_slice(true, false, 1, "1.2")),
          dicom_file("1.2.840.10008.1.2", ct_slice(false, false, 1, "1.2")),
          dicom_file("1.2.840.10008.1.2.2", ct_slice(true, true, 1, "1.2"))};
}

/// `bytes` after 1..max_edits random edits past the 128-byte preamble: a byte changed, the file
/// cut short there, or a byte inserted.
inline std::string mutate(std::string bytes, std::mt19937& rng, int max_edits) {
  const int edits = 1 + static_cast<int>(rng() % static_cast<unsigned>(max_edits));
  for (int e = 0; e < edits; ++e) {
    if (bytes.size() <= 129) break;
    const std::size_t at = 128 + rng() % (bytes.size() - 128);
    switch (rng() % 3) {
      case 0: bytes[at] = static_cast<char>(rng()); break;
      case 1: bytes.resize(at); break;
      default: bytes.insert(at, 1, static_cast<char>(rng())); break;
    }
  }
  return bytes;
}

inline std::size_t find_bytes(const std::string& bytes, std::string_view needle) { return bytes.find(needle); }

}  // namespace lancet::test
