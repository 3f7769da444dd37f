# All third-party libraries come from Debian packages (scripts/setup.sh installs them).
# Each is found here once, so a missing package fails at configure time with its name.
find_package(Threads REQUIRED)
# Header-only parts of Boost (Asio, Beast, CRC; the tests compare with its graph cut).
find_package(Boost 1.74 REQUIRED)
find_package(PkgConfig REQUIRED)
find_package(nanoflann REQUIRED)
# render/ needs OpenCV's core, imgproc, imgcodecs and calib3d; ingest/ also ml and Ceres.
if(HVDB_BUILD_INGEST)
  find_package(OpenCV REQUIRED COMPONENTS core imgproc imgcodecs calib3d ml)
  find_package(Ceres REQUIRED)
else()
  find_package(OpenCV REQUIRED COMPONENTS core imgproc imgcodecs calib3d)
endif()
# What hvdb, hvdb-server, the Python module and the render benchmark link of OpenCV: not
# imgcodecs, whose ~120 shared libraries (GDAL's formats) were most of every command's start;
# formats/image_codec.cc reads and writes pictures with libpng and libjpeg instead (the test
# command checks that those binaries load no GDAL). Ingest, tests and benchmarks use all.
set(HVDB_OPENCV_CORE opencv_core opencv_imgproc opencv_calib3d)
find_package(PNG REQUIRED)
find_package(JPEG REQUIRED)
find_package(draco REQUIRED)
find_package(OpenEXR REQUIRED)
find_package(glm REQUIRED)
# FFmpeg's libraries: videos read by media/ (hvdb import-media) and written by
# render/video_encoder.cc (hvdb render --video, the page's video export); meshes through assimp.
# The product uses their headers and loads them on first use (formats/libav.h); the majors name
# the Debian packages the .deb depends on.
pkg_check_modules(LIBAV REQUIRED IMPORTED_TARGET libavformat libavcodec libswscale libavutil)
foreach(m avformat avcodec avutil swscale)
  string(TOUPPER ${m} upper)
  string(REGEX MATCH "^[0-9]+" HVDB_LIB${upper}_MAJOR "${LIBAV_lib${m}_VERSION}")
  if(NOT HVDB_LIB${upper}_MAJOR)
    message(FATAL_ERROR "no major version for lib${m} from pkg-config ('${LIBAV_lib${m}_VERSION}')")
  endif()
endforeach()
# SPZ version 4 (formats/gaussian_spz.cc): one zstd stream per attribute.
pkg_check_modules(ZSTD REQUIRED IMPORTED_TARGET libzstd)
find_package(assimp REQUIRED)
# media/ loads assimp on first use (media/assimp_lib.h) by the soname of the library found here
# (libassimp.so.5), and the .deb depends on the package of that name (libassimp5).
get_target_property(_assimp_configs assimp::assimp IMPORTED_CONFIGURATIONS)
list(GET _assimp_configs 0 _assimp_config)
get_target_property(HVDB_ASSIMP_SONAME assimp::assimp IMPORTED_SONAME_${_assimp_config})
if(NOT HVDB_ASSIMP_SONAME)
  message(FATAL_ERROR "assimp::assimp names no soname (IMPORTED_SONAME_${_assimp_config})")
endif()
string(REPLACE ".so." "" HVDB_ASSIMP_PACKAGE "${HVDB_ASSIMP_SONAME}")
find_package(OpenGL REQUIRED COMPONENTS EGL OpenGL)
find_package(Protobuf REQUIRED)
find_package(nlohmann_json 3.10 REQUIRED)
find_package(CLI11 REQUIRED)
if(HVDB_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(HVDB_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
