// DICOM element walk: the file meta group (explicit VR little endian), then the data set in the
// transfer syntax's encoding, every sequence and item inside it, and the fragments of compressed
// pixel data. Each read is preceded by a check that the bytes are there; the first problem stops
// the walk and is described with its byte offset.

#include "volume/dicom_scan.hpp"

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <string_view>

namespace lancet::volume {
namespace {

constexpr std::size_t kMarkerAt = 128;          // 'DICM' follows the 128-byte preamble
constexpr std::uint32_t kUndefined = 0xFFFFFFFFu;
constexpr std::size_t kMaxStoredText = 256;     // a field value kept for messages and matching

constexpr std::string_view kVrs[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FD", "FL", "IS", "LO", "LT",
                                     "OB", "OD", "OF", "OL", "OV", "OW", "PN", "SH", "SL", "SQ", "SS", "ST",
                                     "SV", "TM", "UC", "UI", "UL", "UN", "UR", "US", "UT", "UV"};
// VRs whose explicit encoding has two reserved bytes and a 32-bit length.
constexpr std::string_view kLongVrs[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN", "UR", "UT", "UV"};

// Transfer syntaxes whose pixel data is compressed in fragments and that GDCM decodes: RLE,
// JPEG baseline/extended/lossless, JPEG-LS, JPEG 2000.
constexpr std::string_view kCompressed[] = {
    "1.2.840.10008.1.2.5",      "1.2.840.10008.1.2.4.50", "1.2.840.10008.1.2.4.51", "1.2.840.10008.1.2.4.57",
    "1.2.840.10008.1.2.4.70",   "1.2.840.10008.1.2.4.80", "1.2.840.10008.1.2.4.81", "1.2.840.10008.1.2.4.90",
    "1.2.840.10008.1.2.4.91"};

struct Named {
  std::uint16_t group, element;
  const char* name;
};
constexpr Named kNames[] = {
    {0x0002, 0x0010, "TransferSyntaxUID"}, {0x0008, 0x0060, "Modality"},       {0x0020, 0x000E, "SeriesInstanceUID"},
    {0x0028, 0x0002, "SamplesPerPixel"},   {0x0028, 0x0004, "PhotometricInterpretation"},
    {0x0028, 0x0008, "NumberOfFrames"},    {0x0028, 0x0010, "Rows"},           {0x0028, 0x0011, "Columns"},
    {0x0028, 0x0100, "BitsAllocated"},     {0x0028, 0x0101, "BitsStored"},     {0x0028, 0x0102, "HighBit"},
    {0x0028, 0x0103, "PixelRepresentation"}, {0x7FE0, 0x0010, "PixelData"}};

std::string tag_text(std::uint16_t g, std::uint16_t e) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "(%04X,%04X)", static_cast<unsigned>(g), static_cast<unsigned>(e));
  for (const Named& n : kNames) {
    if (n.group == g && n.element == e) return std::string(n.name) + " " + buf;
  }
  return buf;
}

// A value shortened and made printable for a message.
std::string shown(std::string_view s) {
  std::string out;
  for (char c : s.substr(0, 64)) out += (c >= 32 && c < 127) ? c : '?';
  if (s.size() > 64) out += "...";
  return "'" + out + "'";
}

// A DICOM string value without its padding (spaces, NULs).
std::string_view trimmed(std::string_view s) {
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.remove_suffix(1);
  while (!s.empty() && (s.front() == ' ' || s.front() == '\0')) s.remove_prefix(1);
  return s;
}

bool one_of(std::string_view s, std::span<const std::string_view> set) {
  return std::find(set.begin(), set.end(), s) != set.end();
}

struct Encoding {
  bool explicit_vr;
  bool big_endian;
};

class Scanner {
 public:
  Scanner(std::span<const std::uint8_t> bytes, DicomScan& out) : b_(bytes), out_(out) {}

  void run() {
    if (!has_dicom_marker(b_)) {
      out_.status = DicomScanStatus::kNotDicom;
      out_.problem = b_.size() < kMarkerAt + 4 ? "not a DICOM file: " + std::to_string(b_.size()) +
                                                     " bytes, too short for the 128-byte preamble and 'DICM'"
                                               : "not a DICOM file: no 'DICM' marker at byte 128";
      return;
    }
    out_.status = DicomScanStatus::kBroken;  // until the walk completes
    std::size_t pos = kMarkerAt + 4;
    if (!walk({true, false}, pos, b_.size(), 0, Context::kMeta)) return;
    if (!choose_encoding()) return;
    if (!walk({out_.explicit_vr, out_.big_endian}, pos, b_.size(), 0, Context::kTop)) return;
    check_image();
  }

 private:
  enum class Context : std::uint8_t { kMeta, kTop, kItem, kUndefinedItem };

  std::uint16_t u16(std::size_t p, bool big) const {
    return big ? static_cast<std::uint16_t>((b_[p] << 8) | b_[p + 1]) : static_cast<std::uint16_t>(b_[p] | (b_[p + 1] << 8));
  }
  std::uint32_t u32(std::size_t p, bool big) const {
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < 4; ++i) {
      const std::uint32_t byte = b_[p + (big ? i : 3 - i)];
      v = (v << 8) | byte;
    }
    return v;
  }
  std::string_view text(std::size_t p, std::size_t n) const { return {reinterpret_cast<const char*>(b_.data()) + p, n}; }

  bool fail(DicomScanStatus s, std::string message) {
    out_.status = s;
    out_.problem = std::move(message);
    return false;
  }
  bool broken(std::size_t at, const std::string& message) {
    return fail(DicomScanStatus::kBroken, "byte " + std::to_string(at) + ": " + message);
  }

  // Data elements from pos up to end; in kUndefinedItem up to and including the item delimiter,
  // in kMeta up to the first element outside group 0002. pos is left after what was walked.
  bool walk(Encoding enc, std::size_t& pos, std::size_t end, int depth, Context ctx) {
    const char* where = ctx == Context::kItem || ctx == Context::kUndefinedItem ? "the item" : "the file";
    while (true) {
      if (pos == end) {
        if (ctx == Context::kUndefinedItem) {
          return broken(pos, "an item of undefined length ends without its delimiter (FFFE,E00D)");
        }
        return true;
      }
      if (end - pos < 8) {
        return broken(pos, "element header cut off: expected 8 bytes, found " + std::to_string(end - pos) + " before the end of " + where);
      }
      const std::uint16_t g = u16(pos, enc.big_endian), e = u16(pos + 2, enc.big_endian);
      if (ctx == Context::kMeta && g != 0x0002) return true;
      if (g == 0xFFFE) {
        if (e == 0xE00D && ctx == Context::kUndefinedItem) {
          pos += 8;
          return true;
        }
        return broken(pos, "unexpected " + tag_text(g, e) + " (an item or delimiter tag) among data elements");
      }
      const std::size_t at = pos;
      std::string_view vr;
      std::uint32_t len = 0;
      if (enc.explicit_vr) {
        vr = text(pos + 4, 2);
        if (!one_of(vr, kVrs)) {
          return broken(at, tag_text(g, e) + ": expected a value representation (VR) such as 'US' or 'SQ', found " + shown(vr));
        }
        if (one_of(vr, kLongVrs)) {
          if (end - pos < 12) {
            return broken(at, tag_text(g, e) + ": element header cut off: expected 12 bytes, found " + std::to_string(end - pos));
          }
          len = u32(pos + 8, enc.big_endian);
          pos += 12;
        } else {
          len = u16(pos + 6, enc.big_endian);
          pos += 8;
        }
      } else {
        len = u32(pos + 4, enc.big_endian);
        pos += 8;
      }
      const bool pixel_data = ctx == Context::kTop && g == 0x7FE0 && e == 0x0010;

      if (len == kUndefined) {
        if (pixel_data) {
          if (!enc.explicit_vr || (vr != "OB" && vr != "OW")) {
            return broken(at, "PixelData (7FE0,0010): undefined length (compressed fragments) needs explicit VR OB, found " +
                                  (enc.explicit_vr ? shown(vr) : std::string("implicit VR")));
          }
          if (!out_.encapsulated) {
            return broken(at, "PixelData (7FE0,0010): undefined length (compressed fragments), but TransferSyntaxUID (0002,0010) " +
                                  shown(out_.transfer_syntax) + " is uncompressed");
          }
          if (!walk_fragments(pos, end)) return false;
          out_.pixel_element_offset = at;
          continue;
        }
        if (ctx == Context::kMeta || (enc.explicit_vr && vr != "SQ" && vr != "UN")) {
          return broken(at, tag_text(g, e) + ": undefined length on VR " + shown(vr) +
                                ": expected a defined length (only SQ, UN and compressed PixelData may be undefined)");
        }
        // UN of undefined length holds a sequence in implicit VR little endian (PS3.5 6.2.2).
        const Encoding inner = enc.explicit_vr && vr == "UN" ? Encoding{false, false} : enc;
        if (!walk_items(inner, pos, end, true, depth + 1, g, e, at)) return false;
        continue;
      }
      if (len > end - pos) {
        if (pixel_data) {
          return broken(at, "PixelData (7FE0,0010): the file is cut short: expected " + std::to_string(len) +
                                " bytes of pixel data, found " + std::to_string(end - pos));
        }
        return broken(at, tag_text(g, e) + ": expected a value of " + std::to_string(len) + " bytes, found " +
                              std::to_string(end - pos) + " before the end of " + where);
      }
      const std::size_t value_end = pos + len;
      // An implicit-VR sequence of defined length is known only by its first item tag.
      const bool sequence = enc.explicit_vr ? vr == "SQ"
                                            : !pixel_data && len >= 8 && u16(pos, enc.big_endian) == 0xFFFE && u16(pos + 2, enc.big_endian) == 0xE000;
      if (sequence) {
        std::size_t p = pos;
        if (!walk_items(enc, p, value_end, false, depth + 1, g, e, at)) return false;
      } else if (ctx == Context::kMeta || ctx == Context::kTop) {
        if (pixel_data && out_.encapsulated) {
          return broken(at, "PixelData (7FE0,0010): TransferSyntaxUID (0002,0010) " + shown(out_.transfer_syntax) +
                                " is compressed and needs fragments (undefined length), found a defined length of " + std::to_string(len) + " bytes");
        }
        if (!take(g, e, vr, at, pos, len, enc)) return false;
      }
      pos = value_end;
    }
  }

  // The items of a sequence, from pos (after the sequence's header) to end (defined length) or
  // to the sequence delimiter (undefined).
  bool walk_items(Encoding enc, std::size_t& pos, std::size_t end, bool undefined, int depth, std::uint16_t g,
                  std::uint16_t e, std::size_t at) {
    if (depth > kMaxDicomDepth) {
      return broken(at, tag_text(g, e) + ": sequences nested deeper than " + std::to_string(kMaxDicomDepth));
    }
    const std::string seq = "sequence " + tag_text(g, e) + " (from byte " + std::to_string(at) + ")";
    while (true) {
      if (!undefined && pos == end) return true;
      if (end - pos < 8) {
        return broken(pos, seq + ": expected an item (FFFE,E000)" + std::string(undefined ? " or the delimiter (FFFE,E0DD)" : "") +
                               ", found " + std::to_string(end - pos) + " bytes before the end");
      }
      const std::uint16_t ig = u16(pos, enc.big_endian), ie = u16(pos + 2, enc.big_endian);
      const std::uint32_t ilen = u32(pos + 4, enc.big_endian);
      if (ig == 0xFFFE && ie == 0xE0DD && undefined) {
        pos += 8;
        return true;
      }
      if (ig != 0xFFFE || ie != 0xE000) return broken(pos, seq + ": expected an item (FFFE,E000), found " + tag_text(ig, ie));
      const std::size_t item_at = pos;
      pos += 8;
      if (ilen == kUndefined) {
        if (!walk(enc, pos, end, depth, Context::kUndefinedItem)) return false;
        continue;
      }
      if (ilen > end - pos) {
        return broken(item_at, seq + ": an item of " + std::to_string(ilen) + " bytes, found " + std::to_string(end - pos) + " before the end");
      }
      std::size_t p = pos;
      if (!walk(enc, p, pos + ilen, depth, Context::kItem)) return false;
      pos += ilen;
    }
  }

  // Compressed pixel data: a basic offset table item, then fragments, then the delimiter.
  bool walk_fragments(std::size_t& pos, std::size_t end) {
    const std::size_t start = pos;
    std::uint64_t items = 0, total = 0;
    while (true) {
      if (end - pos < 8) {
        return broken(pos, "PixelData (7FE0,0010): compressed fragments cut off: expected an item (FFFE,E000) or the delimiter "
                           "(FFFE,E0DD), found " + std::to_string(end - pos) + " bytes before the end of the file");
      }
      const std::uint16_t g = u16(pos, false), e = u16(pos + 2, false);
      const std::uint32_t len = u32(pos + 4, false);
      if (g == 0xFFFE && e == 0xE0DD) {
        pos += 8;
        break;
      }
      if (g != 0xFFFE || e != 0xE000) {
        return broken(pos, "PixelData (7FE0,0010): expected a fragment item (FFFE,E000), found " + tag_text(g, e));
      }
      if (len == kUndefined || len > end - pos - 8) {
        return broken(pos, "PixelData (7FE0,0010): a fragment of " + (len == kUndefined ? std::string("undefined length") : std::to_string(len) + " bytes") +
                               ", found " + std::to_string(end - pos - 8) + " bytes before the end of the file");
      }
      if (items++ > 0) {
        if (out_.fragments++ == 0) {
          out_.first_fragment_offset = pos + 8;
          out_.first_fragment_length = len;
        }
        total += len;
      }
      pos += 8 + len;
    }
    if (items < 2 || total == 0) {
      return broken(start, "PixelData (7FE0,0010): expected a basic offset table item and at least one fragment of compressed data, found " +
                               std::to_string(items) + " item(s) holding " + std::to_string(total) + " bytes of data");
    }
    out_.has_pixel_data = true;
    out_.pixel_offset = start;
    out_.pixel_length = total;
    return true;
  }

  // Reads a field of the meta group or the top-level data set that shapes the image.
  bool take(std::uint16_t g, std::uint16_t e, std::string_view vr, std::size_t at, std::size_t pos, std::uint32_t len, Encoding enc) {
    const std::string_view value = text(pos, len);
    const auto store = [&](std::string& field) { field = std::string(trimmed(value).substr(0, kMaxStoredText)); };
    const auto number = [&](int& field) {
      if (len == 0) return true;  // empty: as if absent
      if (enc.explicit_vr && vr != "US" && vr != "UN") {
        return broken(at, tag_text(g, e) + ": expected VR 'US', found " + shown(vr));
      }
      if (len < 2) return broken(at, tag_text(g, e) + ": expected a 2-byte unsigned integer, found " + std::to_string(len) + " byte");
      field = u16(pos, enc.big_endian);
      return true;
    };
    switch ((std::uint32_t{g} << 16) | e) {
      case 0x00020010: store(out_.transfer_syntax); return true;
      case 0x00080060: store(out_.modality); return true;
      case 0x0020000E: store(out_.series_uid); return true;
      case 0x00280004: store(out_.photometric); return true;
      case 0x00280002: return number(out_.samples_per_pixel);
      case 0x00280010: return number(out_.rows);
      case 0x00280011: return number(out_.columns);
      case 0x00280100: return number(out_.bits_allocated);
      case 0x00280101: return number(out_.bits_stored);
      case 0x00280102: return number(out_.high_bit);
      case 0x00280103: return number(out_.pixel_representation);
      case 0x00280008: {
        std::string_view t = trimmed(value);
        if (t.empty()) return true;
        if (t.front() == '+') t.remove_prefix(1);
        int n = 0;
        const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), n);
        if (ec != std::errc{} || end != t.data() + t.size()) {
          return broken(at, "NumberOfFrames (0028,0008): expected an integer, found " + shown(trimmed(value)));
        }
        out_.frames = n;
        return true;
      }
      case 0x7FE00010:
        out_.has_pixel_data = true;
        out_.pixel_element_offset = at;
        out_.pixel_offset = pos;
        out_.pixel_length = len;
        return true;
      default: return true;
    }
  }

  bool choose_encoding() {
    const std::string& ts = out_.transfer_syntax;
    if (ts.empty()) {
      return broken(kMarkerAt + 4, "TransferSyntaxUID (0002,0010): expected the field in the file meta group, found none");
    }
    if (ts == "1.2.840.10008.1.2") {
      out_.explicit_vr = false;
    } else if (ts == "1.2.840.10008.1.2.1") {
      out_.explicit_vr = true;
    } else if (ts == "1.2.840.10008.1.2.2") {
      out_.big_endian = true;
    } else if (one_of(ts, kCompressed)) {
      out_.encapsulated = true;
    } else {
      return fail(DicomScanStatus::kUnsupported,
                  "TransferSyntaxUID (0002,0010): expected an uncompressed, RLE, JPEG, JPEG-LS or JPEG 2000 transfer syntax, found " +
                      shown(ts) + (ts == "1.2.840.10008.1.2.1.99" ? " (deflated data sets are not supported)" : ""));
    }
    return true;
  }

  // The image fields against what the loader reads: one frame of 8- or 16-bit greyscale, with
  // all the pixel data there.
  void check_image() {
    DicomScan& s = out_;
    if (!s.has_pixel_data) {
      if (s.rows > 0 || s.columns > 0 || s.bits_allocated > 0) {
        fail(DicomScanStatus::kBroken, "PixelData (7FE0,0010): expected after the image header (Rows, Columns, BitsAllocated), found "
                                       "the end of the file: cut short?");
      } else {
        fail(DicomScanStatus::kNotImage, "no PixelData (7FE0,0010): not an image (a DICOMDIR, a report or other non-image object)");
      }
      return;
    }
    if (s.rows <= 0 || s.columns <= 0) {
      fail(DicomScanStatus::kBroken, "Rows (0028,0010) / Columns (0028,0011): expected positive numbers, found " + std::to_string(s.rows) +
                                         " x " + std::to_string(s.columns) + " (0: missing)");
      return;
    }
    if (s.samples_per_pixel != 1) {
      fail(DicomScanStatus::kUnsupported, "SamplesPerPixel (0028,0002): expected 1 (greyscale), found " + std::to_string(s.samples_per_pixel));
      return;
    }
    if (!s.photometric.empty() && s.photometric != "MONOCHROME1" && s.photometric != "MONOCHROME2") {
      fail(DicomScanStatus::kUnsupported, "PhotometricInterpretation (0028,0004): expected MONOCHROME1 or MONOCHROME2, found " + shown(s.photometric));
      return;
    }
    if (s.bits_allocated != 8 && s.bits_allocated != 16) {
      fail(DicomScanStatus::kUnsupported, "BitsAllocated (0028,0100): expected 8 or 16, found " + std::to_string(s.bits_allocated) + " (0: missing)");
      return;
    }
    if (s.bits_stored == 0) s.bits_stored = s.bits_allocated;
    if (s.bits_stored > s.bits_allocated) {
      fail(DicomScanStatus::kBroken, "BitsStored (0028,0101): expected 1.." + std::to_string(s.bits_allocated) + " (at most BitsAllocated), found " +
                                         std::to_string(s.bits_stored));
      return;
    }
    if (s.high_bit < 0) s.high_bit = s.bits_stored - 1;
    if (s.high_bit < s.bits_stored - 1 || s.high_bit >= s.bits_allocated) {
      fail(DicomScanStatus::kBroken, "HighBit (0028,0102): expected " + std::to_string(s.bits_stored - 1) + ".." +
                                         std::to_string(s.bits_allocated - 1) + " (BitsStored - 1 .. BitsAllocated - 1), found " +
                                         std::to_string(s.high_bit));
      return;
    }
    if (s.pixel_representation != 0 && s.pixel_representation != 1) {
      fail(DicomScanStatus::kBroken, "PixelRepresentation (0028,0103): expected 0 (unsigned) or 1 (signed), found " +
                                         std::to_string(s.pixel_representation));
      return;
    }
    if (s.frames != 1) {
      fail(s.frames > 1 ? DicomScanStatus::kUnsupported : DicomScanStatus::kBroken,
           "NumberOfFrames (0028,0008): expected 1 (one slice per file), found " + std::to_string(s.frames) +
               (s.frames > 1 ? ": multi-frame files are not supported" : ""));
      return;
    }
    if (!s.encapsulated && s.pixel_length < s.frame_bytes()) {
      fail(DicomScanStatus::kBroken, "PixelData (7FE0,0010): expected " + std::to_string(s.frame_bytes()) + " bytes (Rows " +
                                         std::to_string(s.rows) + " x Columns " + std::to_string(s.columns) + " x " +
                                         std::to_string(s.bits_allocated / 8) + " bytes), found " + std::to_string(s.pixel_length));
      return;
    }
    s.status = DicomScanStatus::kImage;
    s.problem.clear();
  }

  std::span<const std::uint8_t> b_;
  DicomScan& out_;
};

}  // namespace

bool has_dicom_marker(std::span<const std::uint8_t> first_bytes) noexcept {
  return first_bytes.size() >= kMarkerAt + 4 && first_bytes[kMarkerAt] == 'D' && first_bytes[kMarkerAt + 1] == 'I' &&
         first_bytes[kMarkerAt + 2] == 'C' && first_bytes[kMarkerAt + 3] == 'M';
}

DicomScan scan_dicom(std::span<const std::uint8_t> bytes) {
  DicomScan out;
  try {
    Scanner(bytes, out).run();
  } catch (const std::exception& e) {  // only allocation can throw here
    out.status = DicomScanStatus::kBroken;
    out.problem = std::string("scan failed: ") + e.what();
  }
  return out;
}

}  // namespace lancet::volume
