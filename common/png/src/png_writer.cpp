#include "storetrack/png/png_writer.hpp"

#include <cstddef>

#ifdef STORETRACK_HAVE_PNG
#include <png.h>
#endif

namespace storetrack::png {

#ifdef STORETRACK_HAVE_PNG
bool available() {
  return true;
}

// libpng reports errors by longjmp back into this frame: it holds no C++ object with a
// destructor and reads nothing after the jump that it set after setjmp (GCC's -Wclobbered, at
// -O1, saw a caller's strings and FILE* live across the setjmp when this was inline there).
bool write_png(std::FILE* fp, const std::uint8_t* pixels, int width, int height, Channels channels,
               std::optional<int> compression_level) {
  png_structp writer = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = writer ? png_create_info_struct(writer) : nullptr;
  if (writer == nullptr || info == nullptr || setjmp(png_jmpbuf(writer))) {
    png_destroy_write_struct(&writer, &info);
    return false;
  }
  png_init_io(writer, fp);
  if (compression_level) png_set_compression_level(writer, *compression_level);
  png_set_IHDR(writer, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               channels == Channels::kRgb ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_GRAY,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(writer, info);
  const std::size_t row_bytes =
      static_cast<std::size_t>(width) * static_cast<std::size_t>(channels);
  for (int y = 0; y < height; ++y)
    png_write_row(writer, pixels + static_cast<std::size_t>(y) * row_bytes);
  png_write_end(writer, nullptr);
  png_destroy_write_struct(&writer, &info);
  return true;
}
#else
bool available() {
  return false;
}

bool write_png(std::FILE*, const std::uint8_t*, int, int, Channels, std::optional<int>) {
  return false;
}
#endif

}  // namespace storetrack::png
