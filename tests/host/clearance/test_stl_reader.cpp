// STL reading (binary, ASCII) and the refusals of docs/clearance.md, each naming the file and
// the triangle: non-finite vertices, degenerate triangles, truncated binary, bad ASCII, and the
// closedness check.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "storetrack/clearance/mesh.hpp"
#include "storetrack/json/text_file.hpp"
#include "synthetic_meshes.hpp"

namespace storetrack::clearance {
namespace {

using test::box;
using test::stl_ascii;
using test::stl_binary;

/// The MeshError of `parse`, or a failure when it does not throw one.
template <typename F>
MeshError refusal(F&& parse) {
  try {
    parse();
  } catch (const MeshError& e) {
    return e;
  }
  ADD_FAILURE() << "no MeshError";
  return MeshError("", std::nullopt, "");
}

TEST(StlReader, BinaryBoxIsReadWithSharedVerticesAndIsClosed) {
  const TriangleMesh m = parse_stl(stl_binary(box({1, 2, 3}, {0.5, 0.25, 0.125})), "box.stl");
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_EQ(m.vertices.size(), 8u);  // bit-identical corners merged
  EXPECT_NO_THROW(check_closed(m));
  EXPECT_DOUBLE_EQ(largest_extent(m), 1.0);
}

TEST(StlReader, BinaryWhoseHeaderStartsWithSolidIsStillBinary) {
  const TriangleMesh m =
      parse_stl(stl_binary(box({0, 0, 0}, {1, 1, 1}), "solid exported"), "b.stl");
  EXPECT_EQ(m.triangles.size(), 12u);
}

TEST(StlReader, AsciiBoxIsReadLikeTheBinaryOne) {
  const TriangleMesh m = parse_stl(stl_ascii(box({1, 2, 3}, {0.5, 0.25, 0.125})), "box.stl");
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_EQ(m.vertices.size(), 8u);
  EXPECT_NO_THROW(check_closed(m));
}

TEST(StlReader, NanVertexInBinaryIsRefusedNamingFileAndTriangle) {
  TriangleMesh m = box({0, 0, 0}, {1, 1, 1});
  m.vertices[static_cast<std::size_t>(m.triangles[5][1])].y() = std::nan("");
  const MeshError e = refusal([&] { parse_stl(stl_binary(m), "nan.stl"); });
  EXPECT_EQ(e.file(), "nan.stl");
  EXPECT_EQ(e.triangle(), 5);
  EXPECT_NE(std::string(e.what()).find("nan.stl: triangle 5: vertex 1 is not finite"),
            std::string::npos)
      << e.what();
}

TEST(StlReader, InfiniteVertexInAsciiIsRefusedNamingTheTriangle) {
  TriangleMesh m = box({0, 0, 0}, {1, 1, 1});
  m.vertices[static_cast<std::size_t>(m.triangles[7][2])].x() =
      std::numeric_limits<double>::infinity();
  const MeshError e = refusal([&] { parse_stl(stl_ascii(m), "inf.stl"); });
  EXPECT_EQ(e.triangle(), 7);
  EXPECT_NE(e.reason().find("not finite"), std::string::npos) << e.what();
}

TEST(StlReader, ZeroAreaTriangleIsRefusedNamingTheTriangle) {
  TriangleMesh m = box({0, 0, 0}, {1, 1, 1});
  test::add_triangle(m, {0, 0, 0}, {1, 1, 1}, {2, 2, 2});  // collinear: triangle 12
  for (const std::string& bytes : {stl_binary(m), stl_ascii(m)}) {
    const MeshError e = refusal([&] { parse_stl(bytes, "flat.stl"); });
    EXPECT_EQ(e.triangle(), 12);
    EXPECT_NE(e.reason().find("degenerate (zero-area)"), std::string::npos) << e.what();
  }
  TriangleMesh repeated = box({0, 0, 0}, {1, 1, 1});
  test::add_triangle(repeated, {0, 0, 0}, {0, 0, 0}, {2, 2, 2});  // two equal corners
  EXPECT_EQ(refusal([&] { parse_stl(stl_binary(repeated), "r.stl"); }).triangle(), 12);
}

TEST(StlReader, ThinButRealTriangleIsAccepted) {
  // Height 1e-4 of a 1 m edge: 100x above the float32 rounding of kDegenerateHeightRatio.
  TriangleMesh m;
  test::add_triangle(m, {0, 0, 0}, {1, 0, 0}, {0.5, 1e-4, 0});
  EXPECT_NO_THROW(parse_stl(stl_binary(m), "thin.stl"));
}

TEST(StlReader, TruncatedBinaryIsRefusedWithCountsAndTheFirstIncompleteTriangle) {
  const std::string full = stl_binary(box({0, 0, 0}, {1, 1, 1}));
  const std::string cut = full.substr(0, 84 + 50 * 9 + 17);  // 9 whole triangles
  const MeshError e = refusal([&] { parse_stl(cut, "cut.stl"); });
  EXPECT_EQ(e.triangle(), 9);
  EXPECT_NE(e.reason().find("truncated: its header states 12 triangles (684 bytes), the file "
                            "has 551 bytes"),
            std::string::npos)
      << e.what();
  EXPECT_NE(
      std::string(refusal([&] { parse_stl(full + "xx", "long.stl"); }).what()).find("wrong size"),
      std::string::npos);
  EXPECT_NE(std::string(refusal([&] { parse_stl(full.substr(0, 40), "short.stl"); }).what())
                .find("shorter than the 84-byte header"),
            std::string::npos);
}

TEST(StlReader, BadAsciiGrammarIsRefusedWithLineAndTriangle) {
  std::string text = stl_ascii(box({0, 0, 0}, {1, 1, 1}));
  const std::size_t third_loop =
      text.find("outer loop", text.find("outer loop", text.find("outer loop") + 1) + 1);
  text.replace(third_loop, 10, "outer lop ");
  const MeshError e = refusal([&] { parse_stl(text, "bad.stl"); });
  EXPECT_EQ(e.triangle(), 2);
  EXPECT_NE(e.reason().find("expected 'loop', found 'lop'"), std::string::npos) << e.what();
  EXPECT_NE(e.reason().find("line 17"), std::string::npos) << e.what();
  EXPECT_THROW(parse_stl("solid x\nendsolid x\n", "empty.stl"), MeshError);  // no triangles
}

TEST(StlReader, OpenMeshIsRefusedByTheClosednessCheck) {
  TriangleMesh m = box({0, 0, 0}, {1, 1, 1});
  m.triangles.pop_back();  // a hole
  const TriangleMesh read = parse_stl(stl_binary(m), "open.stl");
  const MeshError e = refusal([&] { check_closed(read); });
  ASSERT_TRUE(e.triangle().has_value());
  EXPECT_NE(e.reason().find("shared by 1 triangle(s), not 2"), std::string::npos) << e.what();
  // A fin glued twice onto the same edge: three triangles on one edge.
  TriangleMesh doubled = box({0, 0, 0}, {1, 1, 1});
  test::add_triangle(doubled, {-1, -1, -1}, {1, -1, -1}, {0, -3, -1});
  test::add_triangle(doubled, {-1, -1, -1}, {0, -3, -1}, {1, -1, -1});
  EXPECT_NE(refusal([&] { check_closed(parse_stl(stl_binary(doubled), "d.stl")); })
                .reason()
                .find("shared by 4"),
            std::string::npos);
}

TEST(StlReader, MissingFileIsAFileReadError) {
  EXPECT_THROW(read_stl("/nonexistent/store.stl"), jsonfile::FileReadError);
}

}  // namespace
}  // namespace storetrack::clearance
