// common/png's writer against libpng's simplified reader (the decoder the project does not
// write): the pixels, size and colour type come back as written, for grey and RGB; a stream that
// cannot be written is a `false`, not a crash; zlib gets the compression level. Without libpng
// in the build the writer must say so and write nothing.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#ifdef STORETRACK_TEST_HAVE_PNG
#include <png.h>
#endif

#include "storetrack/png/png_writer.hpp"

namespace storetrack::png {
namespace {

namespace fs = std::filesystem;

fs::path temp_file(const std::string& name) {
  return fs::temp_directory_path() / ("storetrack_test_png_" + name);
}

/// Every byte a different function of (x, y, channel): a row or channel mix-up shows.
std::vector<std::uint8_t> pattern(int width, int height, int channels) {
  std::vector<std::uint8_t> out;
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x)
      for (int c = 0; c < channels; ++c)
        out.push_back(static_cast<std::uint8_t>(7 * x + 31 * y + 101 * c));
  return out;
}

bool write_file(const fs::path& path, const std::vector<std::uint8_t>& pixels, int width,
                int height, Channels channels, std::optional<int> level = std::nullopt) {
  std::FILE* fp = std::fopen(path.c_str(), "wb");
  if (fp == nullptr) return false;
  const bool ok = write_png(fp, pixels.data(), width, height, channels, level);
  return std::fclose(fp) == 0 && ok;
}

#ifdef STORETRACK_TEST_HAVE_PNG
struct Decoded {
  int width = 0, height = 0;
  bool colour = false;
  std::vector<std::uint8_t> pixels;  ///< in the file's own format (grey or RGB)
};

Decoded decode(const fs::path& path) {
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&image, path.c_str())) {
    ADD_FAILURE() << path << ": " << image.message;
    return {};
  }
  Decoded out;
  out.width = static_cast<int>(image.width);
  out.height = static_cast<int>(image.height);
  out.colour = (image.format & PNG_FORMAT_FLAG_COLOR) != 0;
  out.pixels.resize(PNG_IMAGE_SIZE(image));
  if (!png_image_finish_read(&image, nullptr, out.pixels.data(), 0, nullptr))
    ADD_FAILURE() << path << ": " << image.message;
  png_image_free(&image);
  return out;
}

/// Writes the pattern and decodes it again: size, colour type and every byte as written.
void expect_round_trip(int width, int height, Channels channels, const std::string& name) {
  ASSERT_TRUE(available());
  const std::vector<std::uint8_t> pixels = pattern(width, height, static_cast<int>(channels));
  const fs::path path = temp_file(name);
  ASSERT_TRUE(write_file(path, pixels, width, height, channels, 1));
  const Decoded d = decode(path);
  EXPECT_EQ(d.width, width);
  EXPECT_EQ(d.height, height);
  EXPECT_EQ(d.colour, channels == Channels::kRgb);
  EXPECT_EQ(d.pixels, pixels);
  fs::remove(path);
}

// Odd sizes: no row padding hides a stride error.
TEST(PngWriter, GreyComesBackAsWritten) {
  expect_round_trip(37, 11, Channels::kGray, "grey.png");
}

TEST(PngWriter, RgbComesBackAsWritten) {
  expect_round_trip(23, 9, Channels::kRgb, "rgb.png");
}

TEST(PngWriter, CompressionLevelReachesZlib) {
  // A flat 256 x 256 image: level 0 stores it (at least its 256 x 257 filtered bytes), libpng's
  // default level deflates it to a few hundred bytes.
  const int side = 256;
  const std::vector<std::uint8_t> flat(static_cast<std::size_t>(side * side), 128);
  const fs::path stored = temp_file("level0.png"), deflated = temp_file("default.png");
  ASSERT_TRUE(write_file(stored, flat, side, side, Channels::kGray, 0));
  ASSERT_TRUE(write_file(deflated, flat, side, side, Channels::kGray));
  EXPECT_GE(fs::file_size(stored), static_cast<std::uintmax_t>(side * (side + 1)));
  EXPECT_LT(fs::file_size(deflated), 2000u);
  EXPECT_EQ(decode(stored).pixels, flat);
  EXPECT_EQ(decode(deflated).pixels, flat);
  fs::remove(stored);
  fs::remove(deflated);
}

TEST(PngWriter, UnwritableStreamIsFalseNotACrash) {
  // libpng's write error longjmps back into the writer, which must return false.
  const fs::path path = temp_file("readonly.png");
  {
    std::FILE* make = std::fopen(path.c_str(), "wb");
    ASSERT_NE(make, nullptr);
    std::fclose(make);
  }
  std::FILE* fp = std::fopen(path.c_str(), "rb");
  ASSERT_NE(fp, nullptr);
  const std::vector<std::uint8_t> grey = pattern(64, 64, 1);
  EXPECT_FALSE(write_png(fp, grey.data(), 64, 64, Channels::kGray));
  std::fclose(fp);
  fs::remove(path);
}
#else
TEST(PngWriter, WithoutLibpngWritesNothing) {
  EXPECT_FALSE(available());
  const fs::path path = temp_file("none.png");
  const std::vector<std::uint8_t> grey = pattern(8, 8, 1);
  EXPECT_FALSE(write_file(path, grey, 8, 8, Channels::kGray));
  EXPECT_EQ(fs::file_size(path), 0u);
  fs::remove(path);
}
#endif

}  // namespace
}  // namespace storetrack::png
