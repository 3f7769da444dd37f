# HVDB_SANITIZE=ON builds everything with ASan + UBSan (see README, "Sanitizers").
if(HVDB_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  add_link_options(-fsanitize=address,undefined)
endif()

# HVDB_FUZZ=ON instruments everything for libFuzzer's coverage (the targets link -fsanitize=fuzzer).
if(HVDB_FUZZ)
  add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()
