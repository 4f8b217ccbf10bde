// The OpenImageIO implementation of ImageCodec (core/data/image_codec.h),
// built as the module libclnerf_oiio.so and loaded on first use. Stateless;
// every method may be called from any thread (OpenImageIO's ImageInput and
// ImageOutput objects are per call).
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <filesystem>
#include <memory>

#include "absl/strings/str_cat.h"
#include "core/data/image_codec.h"

namespace clnerf {
namespace {

absl::StatusOr<RawImage> ReadOpened(OIIO::ImageInput* in, const std::string& name) {
  const OIIO::ImageSpec& spec = in->spec();
  RawImage out;
  out.width = spec.width;
  out.height = spec.height;
  out.channels = spec.nchannels;
  out.premultiplied = spec.get_int_attribute("oiio:UnassociatedAlpha", 0) == 0;
  if (out.width <= 0 || out.height <= 0 || out.channels <= 0 ||
      size_t(out.width) * size_t(out.height) > (size_t(1) << 28)) {
    in->close();
    return absl::InvalidArgumentError(absl::StrCat("image '", name, "' has an invalid size"));
  }
  out.px.resize(size_t(out.width) * out.height * out.channels);
  const bool ok = in->read_image(0, 0, 0, out.channels, OIIO::TypeDesc::FLOAT, out.px.data());
  const std::string error = ok ? "" : in->geterror();
  in->close();
  if (!ok) return absl::InvalidArgumentError(absl::StrCat("cannot decode image '", name, "': ", error));
  return out;
}

class OiioCodec final : public ImageCodec {
 public:
  absl::StatusOr<RawImage> ReadFile(const std::string& path) const override {
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    if (!in) {
      return absl::InvalidArgumentError(absl::StrCat("cannot open image '", path, "': ", OIIO::geterror()));
    }
    return ReadOpened(in.get(), path);
  }

  absl::StatusOr<RawImage> ReadHeader(const std::string& path) const override {
    auto in = OIIO::ImageInput::open(path);
    if (!in) {
      return absl::InvalidArgumentError(absl::StrCat("cannot open image '", path, "': ", OIIO::geterror()));
    }
    RawImage out;
    out.width = in->spec().width;
    out.height = in->spec().height;
    out.channels = in->spec().nchannels;
    in->close();
    return out;
  }

  absl::StatusOr<RawImage> Decode(const std::string& bytes, const std::string& ext,
                                  const std::string& name) const override {
    OIIO::Filesystem::IOMemReader mem(bytes.data(), bytes.size());
    OIIO::ImageSpec config;
    void* ptr = &mem;
    config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &ptr);
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(std::string("memory") + ext, &config);
    if (!in) {
      return absl::InvalidArgumentError(absl::StrCat("cannot decode image '", name, "': ", OIIO::geterror()));
    }
    return ReadOpened(in.get(), name);
  }

  absl::Status WriteFile(const std::string& path, int w, int h, int nc, const uint8_t* px) const override {
    auto out = OIIO::ImageOutput::create(path);
    if (!out) {
      return absl::InvalidArgumentError(absl::StrCat("no image writer for '", path, "': ", OIIO::geterror()));
    }
    OIIO::ImageSpec spec(w, h, nc, OIIO::TypeDesc::UINT8);
    // Our RGBA buffers hold straight (unassociated) colour; without this
    // OpenImageIO would divide by alpha on write.
    if (nc == 4) spec.attribute("oiio:UnassociatedAlpha", 1);
    if (!out->open(path, spec) || !out->write_image(OIIO::TypeDesc::UINT8, px) || !out->close()) {
      return absl::InternalError(absl::StrCat("cannot write '", path, "': ", out->geterror()));
    }
    return absl::OkStatus();
  }

  absl::StatusOr<std::string> Encode(const std::string& ext, int w, int h, int nc, const uint8_t* px,
                                     int quality) const override {
    const std::string name = absl::StrCat("memory.", ext);
    std::vector<unsigned char> buf;
    OIIO::Filesystem::IOVecOutput vec(buf);
    auto out = OIIO::ImageOutput::create(name);
    if (!out) return absl::InternalError(absl::StrCat("no ", ext, " writer: ", OIIO::geterror()));
    OIIO::ImageSpec spec(w, h, nc, OIIO::TypeDesc::UINT8);
    void* ptr = &vec;
    spec.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &ptr);
    if (nc == 4) spec.attribute("oiio:UnassociatedAlpha", 1);  // straight, as WriteFile
    if (quality > 0) spec.attribute("Compression", absl::StrCat("jpeg:", quality));
    if (!out->open(name, spec) || !out->write_image(OIIO::TypeDesc::UINT8, px) || !out->close()) {
      return absl::InternalError(absl::StrCat("cannot encode ", ext, ": ", out->geterror()));
    }
    return std::string(buf.begin(), buf.end());
  }
};

}  // namespace
}  // namespace clnerf

extern "C" __attribute__((visibility("default"))) const clnerf::ImageCodec* CLNERF_IMAGE_CODEC_ENTRY() {
  static const clnerf::OiioCodec codec;
  return &codec;
}
