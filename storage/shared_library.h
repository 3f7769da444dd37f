// A shared library loaded on first use, by soname, with its functions looked up by name.
//
// hvdb's binaries link none of the large libraries that serve rare paths (FFmpeg for videos,
// assimp for meshes): the dynamic loader would map and relocate them, and everything they
// pull in, at every start of every command. The code of such a path loads them here instead,
// once, with an error that names the Debian package to install when one is missing.
#pragma once

#include <string>

#include "storage/status.h"

namespace hvdb {

// dlopen(soname) with RTLD_NOW | RTLD_LOCAL (its symbols stay out of the global namespace,
// where they could interpose on another copy that a library of the process linked). The handle
// is never closed: the libraries keep global state that must outlive any caller.
// Unsupported, naming `purpose`, the soname and its Debian package (the soname without ".so.":
// libassimp.so.5, libassimp5), when it does not load.
Status OpenSharedLibrary(const std::string& soname, const std::string& purpose, void** handle);

// The address of `name` in an opened library; Unsupported (a library other than the one hvdb
// was built with) when it lacks it.
Status SharedLibrarySymbol(void* handle, const std::string& soname, const char* name,
                           void** address);

// The same, typed: `*fn` is a function pointer of the declared type of `name`.
template <typename F>
Status SharedLibraryFunction(void* handle, const std::string& soname, const char* name, F* fn) {
  void* address = nullptr;
  HVDB_RETURN_IF_ERROR(SharedLibrarySymbol(handle, soname, name, &address));
  *fn = reinterpret_cast<F>(address);
  return Status::OK();
}

}  // namespace hvdb
