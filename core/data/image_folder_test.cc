#include "core/data/image_folder.h"

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>

namespace clnerf {
namespace {

namespace fs = std::filesystem;

class ImageFolderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() /
            ("clnerf_image_folder_" + std::to_string(getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    fs::create_directories(root_ / "scene" / "source");
  }
  void TearDown() override { fs::remove_all(root_); }
  fs::path root_;
};

TEST_F(ImageFolderTest, PicksImagesNBesideOrAboveTheModel) {
  const fs::path scene = root_ / "scene", source = scene / "source";
  // Nothing yet: images/ beside the model, to be reported missing later.
  absl::StatusOr<ImageFolder> f = FindImageFolder(source, "", 2.0f);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->path, (source / "images").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 2.0f);

  // images/ one level up (<scene>/source/sparse/0 with <scene>/images).
  fs::create_directories(scene / "images");
  f = FindImageFolder(source, "", 2.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 2.0f);

  // images_2 for a downscale of exactly 2 (nothing left to shrink), not for 3 or 2.5.
  fs::create_directories(scene / "images_2");
  f = FindImageFolder(source, "", 2.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images_2").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 1.0f);
  for (float d : {2.5f, 3.0f}) {
    f = FindImageFolder(source, "", d);
    ASSERT_TRUE(f.ok());
    EXPECT_EQ(f->path, (scene / "images").lexically_normal()) << d;
    EXPECT_FLOAT_EQ(f->residual_downscale, d);
  }
  // A folder beside the model wins over one above it.
  fs::create_directories(source / "images");
  f = FindImageFolder(source, "", 1.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (source / "images").lexically_normal());

  // Explicit folders: relative to the dataset, or absolute; the downscale stays.
  f = FindImageFolder(source, "../images_2", 2.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images_2").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 2.0f);
  f = FindImageFolder(source, (scene / "images").string(), 1.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images").lexically_normal());
  f = FindImageFolder(source, "images_9", 1.0f);
  EXPECT_EQ(f.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(f.status().message().find("images_9"), std::string::npos) << f.status();
}

TEST_F(ImageFolderTest, WithoutImagesFolderTakesTheLargestShrunkCopy) {
  const fs::path scene = root_ / "scene";
  fs::create_directories(scene / "images_8");
  fs::create_directories(scene / "images_4");
  std::ofstream(scene / "images_2") << "a file, not a folder";
  absl::StatusOr<ImageFolder> f = FindImageFolder(scene, "", 1.0f);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->path, (scene / "images_4").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 1.0f);
  // A requested downscale beyond the folder's own is what is left to do.
  f = FindImageFolder(scene, "", 8.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images_8").lexically_normal());  // images_8 exists: exact.
  f = FindImageFolder(scene, "", 6.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images_4").lexically_normal());
  EXPECT_FLOAT_EQ(f->residual_downscale, 1.5f);
  // From a model folder one level down.
  f = FindImageFolder(scene / "source", "", 1.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images_4").lexically_normal());
  // images/ still wins when it exists.
  fs::create_directories(scene / "images");
  f = FindImageFolder(scene, "", 1.0f);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->path, (scene / "images").lexically_normal());
}

TEST_F(ImageFolderTest, ListsImageFilesSorted) {
  const fs::path dir = root_ / "scene" / "images";
  fs::create_directories(dir / "sub.png");  // A folder, not a file.
  for (const char* name : {"b.JPG", "a.png", "c.jpeg", "10.png", "2.png"}) {
    std::ofstream(dir / name) << "x";
  }
  std::ofstream(dir / "notes.txt") << "x";
  std::ofstream(dir / "poses.npy") << "x";
  absl::StatusOr<std::vector<std::string>> files = ListImageFiles(dir);
  ASSERT_TRUE(files.ok()) << files.status();
  EXPECT_EQ(*files, (std::vector<std::string>{"10.png", "2.png", "a.png", "b.JPG", "c.jpeg"}));
  EXPECT_EQ(ListImageFiles(root_ / "nope").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(ImageFolderTest, ScalesIntrinsicsToTheImageSize) {
  Intrinsics in;
  in.width = 720;
  in.height = 1280;
  in.fx = 1100;
  in.fy = 1102;
  in.cx = 360;
  in.cy = 641;
  in.k1 = 0.05f;
  ASSERT_TRUE(ScaleIntrinsicsToImage(360, 640, "a.jpg", &in).ok());
  EXPECT_EQ(in.width, 360);
  EXPECT_EQ(in.height, 640);
  EXPECT_FLOAT_EQ(in.fx, 550);
  EXPECT_FLOAT_EQ(in.fy, 551);
  EXPECT_FLOAT_EQ(in.cx, 180);
  EXPECT_FLOAT_EQ(in.cy, 320.5f);
  EXPECT_FLOAT_EQ(in.k1, 0.05f);  // Normalised coordinates: unchanged.

  // Rounded sizes of images_8 (4946x3286 -> 618x411) scale per axis.
  Intrinsics big;
  big.width = 4946;
  big.height = 3286;
  big.fx = big.fy = 4000;
  big.cx = 2473;
  big.cy = 1643;
  ASSERT_TRUE(ScaleIntrinsicsToImage(618, 411, "b.jpg", &big).ok());
  EXPECT_FLOAT_EQ(big.fx, 4000.0f * 618 / 4946);
  EXPECT_FLOAT_EQ(big.fy, 4000.0f * 411 / 3286);
  EXPECT_FLOAT_EQ(big.cx, 309);
  EXPECT_FLOAT_EQ(big.cy, 205.5f);

  // A rotated image does not fit its calibration.
  absl::Status s = ScaleIntrinsicsToImage(1280, 720, "rotated.jpg", &in);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("rotated.jpg"), std::string::npos) << s;
  EXPECT_EQ(in.width, 360);  // Untouched.
}

}  // namespace
}  // namespace clnerf
