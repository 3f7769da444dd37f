#include "storage/shared_library.h"

#include <dlfcn.h>

namespace hvdb {

Status OpenSharedLibrary(const std::string& soname, const std::string& purpose, void** handle) {
  *handle = dlopen(soname.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (*handle != nullptr) return Status::OK();
  const char* why = dlerror();
  // Debian names a library's package by its soname without ".so." (libassimp.so.5: libassimp5).
  std::string package = soname;
  const size_t so = package.find(".so.");
  if (so != std::string::npos) package.erase(so, 4);
  return Status::Unsupported(purpose + " needs " + soname + ", which did not load (" +
                             (why != nullptr ? why : "unknown reason") + "): apt install " +
                             package);
}

Status SharedLibrarySymbol(void* handle, const std::string& soname, const char* name,
                           void** address) {
  dlerror();
  *address = dlsym(handle, name);
  if (*address != nullptr) return Status::OK();
  return Status::Unsupported(soname + " lacks " + name + ": it is not the version hvdb was " +
                             "built with (reinstall hvdb, or the library's package)");
}

}  // namespace hvdb
