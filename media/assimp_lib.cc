#include "media/assimp_lib.h"

#include <mutex>
#include <string>

#include "storage/shared_library.h"

namespace hvdb::media {

Result<const AssimpLib*> LoadAssimp() {
  static AssimpLib lib;
  static Status status;
  static std::once_flag once;
  std::call_once(once, [] {
    // HVDB_ASSIMP_SONAME: the soname of the library hvdb was built with (media/CMakeLists.txt);
    // Debian's package is named by it (libassimp.so.5: libassimp5).
    const std::string soname = HVDB_ASSIMP_SONAME;
    void* handle = nullptr;
    status = OpenSharedLibrary(soname, "a mesh (assimp)", &handle);
#define HVDB_ASSIMP_LOAD(name) \
  if (status.ok()) status = SharedLibraryFunction(handle, soname, #name, &lib.name);
    HVDB_ASSIMP_FUNCTIONS(HVDB_ASSIMP_LOAD)
#undef HVDB_ASSIMP_LOAD
  });
  if (!status.ok()) return status;
  return &lib;
}

}  // namespace hvdb::media
