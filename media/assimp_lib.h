// assimp, loaded on first use (storage/shared_library.h): libassimp has more relocations than
// the rest of an hvdb binary's libraries together (~44 k), which every command paid at start
// for a path (import-media of a mesh) few of them take. Called through its C API: its C++
// classes cannot be looked up by name.
#pragma once

#include <assimp/cfileio.h>
#include <assimp/cimport.h>
#include <assimp/material.h>
#include <assimp/scene.h>

#include "storage/status.h"

namespace hvdb::media {

// Every assimp function hvdb calls.
#define HVDB_ASSIMP_FUNCTIONS(X)                                                         \
  X(aiCreatePropertyStore) X(aiReleasePropertyStore) X(aiSetImportPropertyInteger)       \
  X(aiImportFileExWithProperties) X(aiReleaseImport) X(aiGetErrorString)                 \
  X(aiGetMaterialColor) X(aiGetMaterialTexture)

struct AssimpLib {
#define HVDB_ASSIMP_MEMBER(name) decltype(&::name) name = nullptr;
  HVDB_ASSIMP_FUNCTIONS(HVDB_ASSIMP_MEMBER)
#undef HVDB_ASSIMP_MEMBER
};

// Loads libassimp once per process (thread-safe) and returns its functions; Unsupported naming
// the package when it is missing. Later calls return the first outcome.
Result<const AssimpLib*> LoadAssimp();

}  // namespace hvdb::media
