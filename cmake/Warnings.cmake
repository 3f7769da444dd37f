# hvdb_warnings(target): the project's warning set; -Werror when HVDB_WERROR is on (CI).
function(hvdb_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow
    -Wnon-virtual-dtor -Wcast-align -Wunused -Woverloaded-virtual -Wimplicit-fallthrough)
  if(HVDB_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()
