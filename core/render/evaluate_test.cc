#include "core/render/evaluate.h"

#include <cmath>
#include <filesystem>

#include "core/data/image.h"
#include "core/testing/temp_dir.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// A 16x12 photo with a gradient in every channel (values in [0.2, 0.8]).
View GradientView(const std::string& name) {
  View v;
  v.name = name;
  v.image = Image(16, 12);
  for (int y = 0; y < 12; ++y) {
    for (int x = 0; x < 16; ++x) {
      float* p = v.image.pixel(x, y);
      p[0] = 0.2f + 0.6f * x / 15.0f;
      p[1] = 0.2f + 0.6f * y / 11.0f;
      p[2] = 0.5f;
    }
  }
  return v;
}

float MaxAbsDiff(const Image& a, const Image& b, float offset) {
  float m = 0;
  for (size_t i = 0; i < a.rgb.size(); ++i) m = std::max(m, std::abs(a.rgb[i] - (b.rgb[i] + offset)));
  return m;
}

// --save-dir writes each render and, beside it, the photo it was scored
// against, so the two can be looked at side by side.
TEST(EvaluateTest, SaveDirWritesEachRenderAndItsPhoto) {
  const std::string dir = testing_util::FreshTempDir("evaluate_save");
  const std::vector<View> views = {GradientView("r_0.png"), GradientView("frames/img_7.jpg")};
  // A renderer 0.1 brighter than the photo: PSNR 20 dB exactly.
  ViewRenderer render = [](const View& v) -> absl::StatusOr<RenderedView> {
    RenderedView r;
    r.rgb = v.image;
    for (float& c : r.rgb.rgb) c += 0.1f;
    return r;
  };
  EvalOptions o;
  o.save_dir = dir + "/renders";
  absl::StatusOr<EvalResult> ev = EvaluateWith(render, views, o);
  ASSERT_TRUE(ev.ok()) << ev.status();
  EXPECT_NEAR(ev->psnr, 20.0, 1e-3);
  const std::pair<const char*, const char*> files[] = {{"0000_r_0.png", "0000_r_0.photo.png"},
                                                        {"0001_img_7.png", "0001_img_7.photo.png"}};
  for (size_t k = 0; k < 2; ++k) {
    absl::StatusOr<Image> rendered = ReadImage(o.save_dir + "/" + files[k].first);
    absl::StatusOr<Image> photo = ReadImage(o.save_dir + "/" + files[k].second);
    ASSERT_TRUE(rendered.ok()) << rendered.status();
    ASSERT_TRUE(photo.ok()) << photo.status();
    ASSERT_EQ(photo->width, 16);
    ASSERT_EQ(photo->height, 12);
    // 8-bit PNGs: within a code (and sRGB-free: the files hold the values).
    EXPECT_LE(MaxAbsDiff(*photo, views[k].image, 0.0f), 1.0f / 255.0f);
    EXPECT_LE(MaxAbsDiff(*rendered, views[k].image, 0.1f), 1.0f / 255.0f);
  }
}

}  // namespace
}  // namespace clnerf
