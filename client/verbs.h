// The list of `clnerf` verbs: RegisterVerbs adds every verb (and the `bench`
// group) to a VerbSet, in the order --help shows them. The one place a new
// verb is listed; its flags and its code live in its own file. Not
// thread-safe (CLI set-up).
#ifndef CLNERF_CLIENT_VERBS_H_
#define CLNERF_CLIENT_VERBS_H_

#include "client/verb_set.h"

namespace clnerf {

void RegisterVerbs(VerbSet* verbs);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_VERBS_H_
