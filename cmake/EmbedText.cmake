# Writes OUT, a .cc defining bp::internal::kDefaultCellYaml with the text of IN.
file(READ ${IN} _text)
file(WRITE ${OUT} "// Generated from ${IN}; do not edit.\n#include <string_view>\nnamespace bp::internal {\nextern const std::string_view kDefaultCellYaml;\nconst std::string_view kDefaultCellYaml = R\"BPCELL(${_text})BPCELL\";\n}  // namespace bp::internal\n")
