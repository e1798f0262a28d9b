#include <cstdio>
int main() { std::puts("softdiff: under construction"); return 0; }
