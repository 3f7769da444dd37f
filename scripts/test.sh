#!/usr/bin/env bash
# Runs every test: the layer map check, set-up (packages + warnings-as-errors build), the full CTest suite, then
# the storage, server, codec and ingest point tests again under AddressSanitizer +
# UndefinedBehaviorSanitizer, then the decoders under libFuzzer.
set -euo pipefail
cd "$(dirname "$0")/.."

# The layer map first (a second, before any build): includes and links between the folders as
# docs/ARCHITECTURE.md draws them, and no source file over 800 lines. ctest runs it too.
/usr/bin/python3 scripts/check_layers.py

bash scripts/setup.sh --all
ctest --test-dir build --output-on-failure -j2 --timeout 900

# Sanitizers: a separate Debug build of the storage (the Gaussian column too), server, executor
# and codec tests, the Gaussian-splat file readers (GLB and SPZ version 4 too), the SH-rotating
# transforms and the 3DGS rasteriser (and its differentiable twin), and of
# ingest's point stages (photo-consistency's vector loops, billboards, segmentation). The tests that bound
# the server's resident memory are left out (ASan's shadow memory and quarantine are what they
# would measure), and so is photo-consistency's throughput test, and the photo video tier's
# 160 full-HD pictures (its other tests, crashes included, run).
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DHVDB_SANITIZE=ON -DHVDB_WERROR=ON \
  -DHVDB_BUILD_BENCH=OFF >/dev/null
cmake --build build-asan --target storage_tests server_tests service_tests codec_tests \
  blockcode_tests ingest_points_tests photo_video_tests gaussian_files_tests gaussian_raster_tests \
  gaussian_glb_tests gaussian_transform_tests gaussian_grad_tests
ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir build-asan --output-on-failure -j2 --timeout 900 \
  -R '^(Crc32c|Point|BufferPool|ConvertTest|ServiceTest|Lod|KdTree|Hyperslice|Wal|Dataset|FollowerTest|WatchTest|WatchServerTest|Photos|PhotoVideo|Crash|Corruption|ColdTier|RecordBlock|FaultInjection|Server|HttpServer|Hardening|HttpHeadCheck|Printable|WsCodec|WebPath|OriginAllowed|CodecTest|DepthSigma|PhotoConsistency|GeometricConsistencyTest|BillboardTest|SegmentationTest|ImportMediaLimitsTest|RequestTableTest|ExecuteUnaryTest|RenderConvertTest|GaussianCorpus|GaussianPly|Gaussians\.|Splat\.|Spz\.|GaussianColumn|GaussianRaster|GaussianGlb|GaussianTransform|GaussianGradTest)' \
  -E 'SlowReaderDoesNotGrowServerMemory|PipelinedQueriesOfClientsThatDoNotRead|TheServerWideBudgetHolds|PingsOfAClientThatDoesNotRead|PingPayloadsOverTheLimit|ConnectionsBeforeTheirHelloCannotAnnounce|AClientThatNeverReleasesHoldsOnlyItsRing|ClientsKilledWhileHoldingSlotsLeakNothing|PhotoConsistency.Throughput|PanopticViewsReadBack|ServedEveryFileIsRefusedTheServerKeepsServingWithinItsBudget|AValidPictureOfAQuarterGigapixel|AMillionSplatsAreFast'

# Fuzz the decoders with clang's libFuzzer, 20 seconds each: the frame and message decoder of
# the socket protocol, the WebSocket messages and HTTP requests of the browser's, the hvdb7
# point-stream decoder, its octree geometry on its own, and the cold tier's record blocks (blockcode/), the photo files, the log
# records and the Gaussian column's segments of storage/, the image decoder and Gaussian-splat readers of formats/, and
# import-media's image, video and mesh decoders (media/; the mesh parser runs in a child
# process, whose crashes are the request's error: their reports land in the temporary corpus,
# the run goes on).
CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DHVDB_FUZZ=ON -DHVDB_BUILD_BENCH=OFF >/dev/null
cmake --build build-fuzz --target frame_decoder_fuzz ws_message_fuzz http_request_fuzz \
  hvdb7_decoder_fuzz octree_fuzz photo_decoder_fuzz wal_record_fuzz image_codec_fuzz \
  record_block_fuzz media_import_fuzz gaussian_files_fuzz gaussian_segment_fuzz
for target in frame_decoder_fuzz:server/fuzz_corpus ws_message_fuzz:server/ws_fuzz_corpus \
  http_request_fuzz:server/http_fuzz_corpus \
  hvdb7_decoder_fuzz:codec/fuzz_corpus octree_fuzz:codec/octree_fuzz_corpus \
  photo_decoder_fuzz:storage/photo_fuzz_corpus \
  wal_record_fuzz:storage/wal_fuzz_corpus image_codec_fuzz:formats/image_fuzz_corpus \
  gaussian_segment_fuzz:storage/gaussian_segment_fuzz_corpus \
  gaussian_files_fuzz:formats/gaussian_fuzz_corpus \
  record_block_fuzz:blockcode/record_block_fuzz_corpus \
  media_import_fuzz:media/import_fuzz_corpus; do
  corpus=$(mktemp -d)
  cp "tests/${target#*:}"/* "$corpus"/
  LSAN_OPTIONS=suppressions=$PWD/tests/media/lsan_suppressions.txt \
    "build-fuzz/tests/${target%%:*}" -max_total_time=20 -rss_limit_mb=2048 \
    -artifact_prefix="$corpus/" "$corpus" 2>&1 | tail -n 2
  rm -rf "$corpus"
done
echo "test: all suites passed"
